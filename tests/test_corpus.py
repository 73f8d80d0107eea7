"""The benchmark corpus (benchmarks/corpus.py, corpus_scenes.py) and its Mitsuba export
(benchmarks/mitsuba_export.py): every scene builds and validates, the training/validation split
is the fixed one and balanced by kind, and, where Mitsuba is installed (the ``peers`` extra;
CI has none, so these skip there), the export puts every shape, instance and light where warprt
has it and lights it the same, and the Whitted integrator written for Mitsuba gives the same
image as Mitsuba's ``direct`` where there is no mirror. Nothing here renders a big scene.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

import warprt
from benchmarks import corpus, corpus_scenes as cs
from benchmarks import mitsuba_export as mx

# the validation half, fixed once: changing it would let a tuned constant see the scenes that
# report on it (benchmarks/corpus.py)
VALIDATION = {"room-shelves", "instances-mixed-200", "three-sphere-lights", "mixed-32", "mirror-room", "glass-mesh",
              "mesh-80k", "mesh-2m", "lens-instances", "moving-mesh-camera", "street-1080p", "bin-128",
              "contact-figures", "checker", "disk-penumbrae"}

# what the issue asks the corpus to cover
KINDS = {"room lit from the ceiling", "instances", "sphere and disk lights", "many lights", "mirrors", "glass",
         "meshes", "thin lens", "motion blur", "high resolution", "robot camera", "contact shadows", "edges",
         "penumbrae"}


@pytest.fixture(scope="module")
def built():
    return {e.name: e.build() for e in corpus.CORPUS}


def test_the_split_is_fixed_and_balanced_by_kind():
    assert len(corpus.CORPUS) >= 24
    assert len({e.name for e in corpus.CORPUS}) == len(corpus.CORPUS)
    assert {e.name for e in corpus.CORPUS if e.split == corpus.VALIDATION} == VALIDATION
    assert {e.split for e in corpus.CORPUS} == {corpus.TRAIN, corpus.VALIDATION}
    assert set(corpus.KINDS) == KINDS
    for kind in KINDS:  # every kind on both sides
        sides = Counter(e.split for e in corpus.CORPUS if e.kind == kind)
        assert sides[corpus.TRAIN] >= 1 and sides[corpus.VALIDATION] >= 1, kind
    n = Counter(e.split for e in corpus.CORPUS)
    assert abs(n[corpus.TRAIN] - n[corpus.VALIDATION]) <= 1
    assert [e.name for e in corpus.entries("validation")] == [e.name for e in corpus.CORPUS if e.name in VALIDATION]
    assert corpus.entries("all", kinds=["glass"]) == [corpus.BY_NAME["glass-ball"], corpus.BY_NAME["glass-mesh"]]


def test_every_scene_builds_valid_and_exportable(built):
    for e in corpus.CORPUS:
        scene = built[e.name]
        assert isinstance(scene, warprt.Scene), e.name
        # the renderer's defaults decide: no render option set in the scene, area lights with
        # their default light samples
        assert scene.render == warprt.RenderSettings(), e.name
        for light in scene.lights:
            if hasattr(light, "samples"):
                assert light.samples == type(light)().samples, e.name
            if isinstance(light, warprt.PointLight):
                assert light.falloff == "inverse_square", e.name
        # the same physics in Mitsuba: no ambient, no background, exportable materials
        assert not np.any(scene.ambient) and not np.any(scene.background), e.name
        for s in scene.shapes:
            assert mx.material_kind(scene.materials[s.material]) in ("lambert", "mirror", "glass")
        assert (corpus.BY_NAME[e.name].kind == "motion blur") == mx.moves(scene), e.name
        assert mx.has_specular(scene) == (e.kind in ("mirrors", "glass")), e.name


def test_each_kind_has_what_it_says(built):
    by = {e.name: (e, built[e.name]) for e in corpus.CORPUS}
    tris = {n: cs.tri_count(s) for n, (_, s) in by.items()}
    assert tris["mesh-1k"] < 3000 and 80_000 <= tris["mesh-80k"] < 90_000
    assert 500_000 <= tris["mesh-500k"] < 600_000 and 2_000_000 <= tris["mesh-2m"] < 2_200_000
    for n, (e, s) in by.items():
        w, h = s.camera.width, s.camera.height
        if e.kind == "high resolution":
            assert w >= 1280 and h >= 720, n
        if e.kind == "robot camera":
            assert 64 <= w <= 128 and 64 <= h <= 128, n
            assert {warprt.Box, warprt.Capsule, warprt.Cylinder, warprt.Mesh} <= {type(x) for x in s.shapes}, n
        if e.kind == "thin lens":
            assert s.camera.aperture > 0, n
        if e.kind == "many lights":
            assert 8 <= len(s.lights) <= 64, n
        if e.kind == "instances":
            meshes = [x for x in s.shapes if isinstance(x, warprt.Mesh)]
            assert len(meshes) >= 40 and len({id(x.vertices) for x in meshes}) <= 3, n
            assert any(x.transform.uniform_scale is None for x in meshes), n  # some stretched
        if e.kind == "sphere and disk lights":
            assert {warprt.SphereLight, warprt.DiskLight} <= {type(x) for x in s.lights}, n
        if e.kind == "contact shadows":
            assert any(isinstance(x, warprt.Plane) for x in s.shapes), n
    assert sum(len(s.lights) for _, s in by.values() if len(s.lights) >= 8) >= 8 + 32 + 64 - 8


def test_scenes_are_the_same_on_every_build():
    for name in ("instances-mixed-200", "bin-128", "spheres-64"):
        e = corpus.BY_NAME[name]
        assert mx.scene_digest(e.build()) == mx.scene_digest(e.build()), name
    a, b = corpus.BY_NAME["fence"].build(), corpus.BY_NAME["checker"].build()
    assert mx.scene_digest(a) != mx.scene_digest(b)


def test_scene_at_time_interpolates_the_poses():
    scene = cs.moving_mesh_camera(32, 32)
    mid = mx.scene_at_time(scene, 0.5)
    assert not mx.moves(mid) and mx.moves(scene)
    np.testing.assert_allclose(mid.camera.eye, (0.0, 1.6, 4.0), atol=1e-12)
    mesh0 = next(s for s in scene.shapes if isinstance(s, warprt.Mesh))
    mesh_mid = next(s for s in mid.shapes if isinstance(s, warprt.Mesh))
    np.testing.assert_allclose(mesh_mid.transform.translate, (0.0, 0.65, 0.0), atol=1e-12)
    # the rotation halfway: the same angle from both ends (slerp)
    q0, q1, qm = mesh0.transform.quaternion(), mesh0.transform_end.quaternion(), mesh_mid.transform.quaternion()
    angle = lambda a, b: 2 * math.acos(min(1.0, abs(float(np.dot(a, b)))))  # noqa: E731
    assert angle(q0, qm) == pytest.approx(angle(qm, q1), abs=1e-9) and angle(q0, qm) > 0.1
    spheres = cs.moving_spheres(32, 32)
    s1 = mx.scene_at_time(spheres, 0.25).shapes[1]
    np.testing.assert_allclose(s1.center, (-1.0, 0.3, 0.0), atol=1e-12)


def test_moving_scenes_refuse_to_export():
    pytest.importorskip("mitsuba")  # (to_mitsuba needs the module for its transforms)
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    with pytest.raises(mx.ExportError, match="animated"):
        mx.to_mitsuba(cs.moving_spheres(16, 16), mi)


def test_list_prints_the_corpus(capsys):
    assert corpus.main(["--list"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == len(corpus.CORPUS) + 1 and "training" in out[-1]


def test_main_without_mitsuba_says_so_and_exits_0(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(corpus, "load_mitsuba", lambda variant="llvm_ad_rgb", threads=2: None)
    assert corpus.main(["--quick", "--scenes", "fence", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "Mitsuba" in out[0]


def test_summary_geometric_mean_and_worst():
    def rec(name, split, r):
        return {"name": name, "split": split, "ratios": {"0.001": {"a": {"ratio": r, "bound": "", "per_repeat": [r, 2 * r]}},
                                                        "0.01": {}}}

    results = {"configs": ["a"], "scenes": {"x": rec("x", "train", 0.5), "y": rec("y", "train", 2.0),
                                           "z": rec("z", "validation", 3.0)}}
    s = corpus.summarise(results)
    assert s["train"]["a"]["0.001"]["geomean"] == pytest.approx(1.0)
    assert s["train"]["a"]["0.001"]["worst"] == 2.0 and s["train"]["a"]["0.001"]["worst_scene"] == "y"
    assert s["train"]["a"]["0.001"]["geomean_per_repeat"] == pytest.approx([1.0, 2.0])
    assert s["validation"]["a"]["0.001"]["geomean"] == pytest.approx(3.0)


# --- with Mitsuba (skipped where the peers extra is not installed) -------------------------------------


@pytest.fixture(scope="module")
def mi():
    mitsuba = pytest.importorskip("mitsuba")
    import drjit as dr

    mitsuba.set_variant("scalar_rgb")
    mitsuba.set_log_level(mitsuba.LogLevel.Error)
    dr.set_thread_count(2)
    mx.register_whitted(mitsuba)
    return mitsuba


def _geometry_scene():
    """Every shape kind the corpus uses, instanced meshes stretched and turned, and every light."""
    ring = cs.torus(24, 12, 0.3, 0.1)
    shapes = (
        cs.ground(),
        warprt.Sphere(center=(-1.2, 0.4, 0.0), radius=0.4, material="m"),
        warprt.Rectangle(corner=(-2.0, 0.0, -2.0), edge1=(0.0, 1.0, 0.0), edge2=(1.0, 0.0, 0.2), material="m"),
        warprt.Disk(center=(1.8, 0.8, -1.0), normal=(0.3, 0.2, 1.0), radius=0.3, material="m"),
        warprt.Box(center=(0.1, 0.0, 0.0), size=(0.5, 0.3, 0.7), material="m",
                   transform=warprt.Transform(translate=(0.0, 0.4, -0.8), rotate=(10, 35, -20), scale=(1.0, 1.5, 0.8))),
        warprt.Cylinder(start=(1.0, 0.0, 0.0), end=(1.3, 0.9, 0.2), radius=0.2, material="m"),
        warprt.Capsule(start=(-0.3, 0.2, 0.8), end=(0.4, 0.5, 0.9), radius=0.15, material="m"),
        cs.mesh(ring, "m", warprt.Transform(translate=(0.5, 1.2, 0.3), rotate=(70, 20, 5), scale=(1.6, 0.7, 1.1))),
        cs.mesh(ring, "m", warprt.Transform(translate=(-0.6, 1.3, -0.4), rotate=(-30, 80, 0), scale=(0.6, 1.8, 1.0))),
    )
    lights = (warprt.DiskLight(center=(0.0, 2.5, 0.0), normal=(0.2, -1.0, 0.1), radius=0.5, radiance=3.0),
              warprt.RectLight(corner=(1.5, 2.0, 1.0), edge1=(0.5, 0.0, 0.0), edge2=(0.0, -0.2, 0.5), radiance=2.0),
              warprt.SphereLight(center=(-1.5, 2.0, 1.0), radius=0.3, radiance=2.0))
    return warprt.Scene(camera=cs.camera((0.0, 2.0, 5.0), (0.0, 0.6, 0.0), 50.0, (32, 24)), shapes=shapes,
                        materials={"ground": cs.lambert(0.5), "m": cs.lambert(0.7)}, lights=lights)


@pytest.mark.parametrize("instancing", [True, False])
def test_export_puts_every_shape_and_instance_where_warprt_has_it(mi, tmp_path, instancing):
    """Rays from many directions: the distance to the first hit and the geometric normal (up
    to the side, except for lights: one-sided emitters must face the same way) agree between
    warprt's trace_rays and Mitsuba's ray_intersect on every shape kind, stretched and turned
    mesh instances included (Transform.matrix() is Mitsuba's to_world convention)."""
    scene = _geometry_scene()
    m = mi.load_dict(mx.to_mitsuba(scene, mi, mesh_dir=tmp_path, instancing=instancing))
    rng = np.random.default_rng(1)
    # rays from points around the scene towards points in it, and straight at each light
    o = rng.uniform((-3, 0.2, -3), (3, 3.5, 4), size=(400, 3))
    target = rng.uniform((-2, 0.0, -2), (2, 2.0, 1.5), size=(400, 3))
    lights = np.array([[0.0, 2.5, 0.0], [1.75, 1.9, 1.25], [-1.5, 2.0, 1.0]])
    o = np.concatenate([o, np.repeat([[0.3, 0.5, 0.4]], 30, axis=0)])
    target = np.concatenate([target, lights[rng.integers(0, 3, 30)] + rng.normal(0, 0.05, (30, 3))])
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w = warprt.trace_rays(scene, o, d)
    agree, lit = 0, 0
    for i in range(len(o)):
        si = m.ray_intersect(mi.Ray3f(mi.Point3f(*o[i]), mi.Vector3f(*d[i])))
        if w["hit"][i] and np.abs(w["position"][i]).max() > mx.GROUND_HALF:
            continue  # the infinite ground beyond Mitsuba's square
        assert bool(si.is_valid()) == bool(w["hit"][i]), i
        if not w["hit"][i]:
            continue
        assert float(si.t) == pytest.approx(float(w["t"][i]), rel=2e-4, abs=2e-4), i
        n_m, n_w = np.array(si.n), w["normal"][i].astype(float)
        assert abs(float(np.dot(n_m, n_w))) == pytest.approx(1.0, abs=1e-3), i
        if si.shape.is_emitter():
            lit += 1
            assert float(np.dot(n_m, n_w)) > 0.99, i  # the emitting side is the same
        agree += 1
    assert agree > 300 and lit >= 15


def _same_within_noise(a_batches, b_batches):
    """Two renderers' images the same within their noise, pixel by pixel: each side's k
    independent batches give its per-pixel mean and the variance of that mean, z = the
    difference over their combined σ (a Student t with about 2(k - 1) degrees of freedom per
    value where the images agree). A pixel-by-pixel test, so that the few bright pixels of a
    light seen in a mirror cannot hide, or fake, a difference elsewhere. Returns (fraction of
    values with |z| > 4, median |z|, image-mean difference over its σ)."""
    a, b = np.stack(a_batches), np.stack(b_batches)
    k = len(a)
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    var = a.var(axis=0, ddof=1) / k + b.var(axis=0, ddof=1) / len(b)
    tiny = (1e-6 * float(np.mean(ma))) ** 2
    z = (ma - mb) / np.sqrt(var + tiny)
    per_image = np.stack([x.mean() for x in a]), np.stack([x.mean() for x in b])
    sigma = math.sqrt(per_image[0].var(ddof=1) / k + per_image[1].var(ddof=1) / len(b))
    return float(np.mean(np.abs(z) > 4)), float(np.median(np.abs(z))), abs(float(ma.mean() - mb.mean())) / sigma


def _mitsuba_batches(mi, d, spp, seeds):
    s = mi.load_dict(d)
    return [np.array(mi.render(s, spp=spp, seed=k), dtype=np.float64) for k in seeds]


def test_whitted_integrator_matches_mitsubas_direct_without_mirrors(mi, tmp_path):
    """On a Lambert scene with every light kind, the Whitted integrator is Mitsuba's direct
    integrator: the same image within the noise of independent renders (other seeds), pixel by
    pixel."""
    d = mx.to_mitsuba(_geometry_scene(), mi, sampler="independent", mesh_dir=tmp_path)
    direct = _mitsuba_batches(mi, d, 64, seeds=range(10, 18))
    d["integrator"] = {"type": "whitted", "max_depth": 5}
    whitted = _mitsuba_batches(mi, d, 64, seeds=range(20, 28))
    outliers, median, mean_z = _same_within_noise(direct, whitted)
    assert outliers < 0.01 and median < 1.0 and mean_z < 4, (outliers, median, mean_z)
    assert np.mean(direct[0]) > 0.02


@pytest.mark.slow
def test_lights_and_whitted_recursion_agree_with_warprt(mi, tmp_path):
    """warprt and Mitsuba (scalar_rgb) on one small scene with a mirror sphere, a glass ball
    (exact Fresnel; warprt's shadow rays pass it with kt), a sphere light, a disk light, a point
    light and a directional light over the ground to the horizon: the same image within their
    noise, pixel by pixel."""
    scene = warprt.Scene(
        camera=cs.camera((0.0, 1.3, 3.5), (0.0, 0.5, 0.0), 45.0, (32, 24)),
        shapes=(cs.ground(), warprt.Sphere(center=(-0.6, 0.4, 0.0), radius=0.4, material="mirror"),
                warprt.Sphere(center=(0.5, 0.35, 0.3), radius=0.35, material="glass"),
                warprt.Box(center=(0.3, 0.3, -0.8), size=(0.6, 0.6, 0.6), material="m")),
        materials={"ground": cs.lambert(0.5), "m": cs.lambert((0.7, 0.3, 0.2)), "mirror": cs.MIRROR,
                   "glass": cs.GLASS},
        lights=(warprt.SphereLight(center=(-1.0, 2.0, 1.0), radius=0.2, radiance=15.0),
                warprt.DiskLight(center=(1.0, 2.0, 0.5), normal=(-0.3, -1.0, 0.0), radius=0.3, radiance=10.0),
                cs.point_light((0.0, 2.5, 2.0), 2.0), cs.sun((0.3, -1.0, -0.2), 0.8)))
    d = mx.to_mitsuba(scene, mi, sampler="independent", mesh_dir=tmp_path)
    assert d["integrator"]["type"] == "whitted" and d["integrator"]["transparent_shadows"]
    m = _mitsuba_batches(mi, d, 256, seeds=range(10, 18))
    r = warprt.Renderer(scene.with_settings(sampler="sobol"), device="cpu")
    w = [r.render(spp=64, seed=k, workers=2, progress=False).image.astype(np.float64) for k in range(1, 9)]
    outliers, median, mean_z = _same_within_noise(m, w)
    assert outliers < 0.01 and median < 1.0 and mean_z < 4, (outliers, median, mean_z)


def test_the_docs_list_the_corpus_as_it_is():
    text = (corpus.ROOT / "docs" / "benchmarks.md").read_text()
    for e in corpus.CORPUS:
        split = "training" if e.split == corpus.TRAIN else "validation"
        assert f"| {e.name} | {e.kind} | {split} |" in text, e.name
    assert corpus.MARK_BEGIN in text and corpus.MARK_END in text
