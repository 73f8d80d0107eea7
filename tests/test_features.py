"""A scene pays only for what it uses: feature detection, specialised kernels that give the same
image as the all-features kernel, shared mesh assets, and the sphere BVH."""

from __future__ import annotations

import dataclasses
import importlib
import math

import numpy as np
import pytest

import warprt
from warprt import Features
from warprt import build as build_module
from warprt import accel

render_module = importlib.import_module("warprt.render")  # (``warprt.render`` is also the function)


def _scene(**kw) -> warprt.Scene:
    base = dict(camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.4, 0), width=24, height=16),
                shapes=(warprt.Plane(material="floor"), warprt.Sphere(center=(0, 0.5, 0), radius=0.5, material="ball")),
                materials={"floor": warprt.Material(kd=0.7), "ball": warprt.Material(kd=(0.8, 0.2, 0.1), ks=0.4, p=40)},
                lights=(warprt.PointLight(position=(2, 3, 2), intensity=0.8),), ambient=0.05)
    base.update(kw)
    return warprt.Scene(**base)


def features_of(scene: warprt.Scene) -> Features:
    return warprt.Renderer(scene, device="cpu").features


def test_plain_scene_needs_no_optional_feature():
    assert features_of(_scene()) == Features()


@pytest.mark.parametrize("change, flag", [
    (dict(materials={"floor": warprt.Material(mirror=0.5), "ball": warprt.Material()}), "secondary"),
    (dict(materials={"floor": warprt.Material(), "ball": warprt.Material(transparency=1.0)}), "refraction"),
    (dict(materials={"floor": warprt.Material(mirror=0.5, glossy_exponent=30), "ball": warprt.Material()}), "glossy"),
    # clear glass without mirror or Fresnel still reflects (total internal reflection), and
    # those reflections take the glossy lobe: the specialised kernel must include it
    (dict(materials={"floor": warprt.Material(), "ball": warprt.Material(transparency=1.0, glossy_exponent=20)}),
     "glossy"),
    (dict(lights=(warprt.SphereLight(),)), "area_lights"),
    (dict(camera=warprt.Camera(aperture=0.1)), "lens"),
    (dict(camera=warprt.Camera(eye_end=(1, 0, 5))), "motion"),
    (dict(shapes=(warprt.Sphere(center_end=(1, 0, 0)),)), "motion"),
    (dict(shapes=(warprt.Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]]),)), "meshes"),
    (dict(shapes=(warprt.Sphere(), warprt.Disk(center=(2, 0, 0)))), "analytic_bvh"),
    (dict(shapes=(warprt.Plane(), warprt.Rectangle()), lights=(warprt.RectLight(),)), "analytic_bvh"),
])
def test_each_feature_is_detected(change, flag):
    assert getattr(features_of(_scene(**change)), flag)


def test_unused_materials_add_no_feature():
    scene = _scene(materials={"floor": warprt.Material(), "ball": warprt.Material(),
                              "unused_glass": warprt.Material(transparency=1.0, glossy_exponent=10)})
    assert features_of(scene) == Features()


@pytest.mark.parametrize("scene", [
    _scene(),
    _scene(materials={"floor": warprt.Material(kd=0.5, mirror=0.4), "ball": warprt.Material(kd=0.2, mirror=0.7)}),
], ids=["plain", "mirrors"])
def test_specialised_kernel_matches_the_full_kernel_bit_for_bit(device, scene):
    specialised = warprt.Renderer(scene, device=device)
    full = warprt.Renderer(scene, device=device, features=Features.full())
    assert specialised.features != full.features
    a = specialised.render(spp=4, progress=False).image
    b = full.render(spp=4, progress=False).image
    assert a.tobytes() == b.tobytes()



def test_camera_rays_one_by_one_give_the_packets_images_bit_for_bit(device):
    """``packets=False`` (camera rays one by one, CUDA's default: ``integrator.packets_for``)
    renders what camera packets (the CPU's default) render, bit for bit: every scene file with
    the all-features kernel (secondary rays, refraction, glossy lobes, a lens, motion, solids,
    meshes, area lights), against the saved CPU images on the CPU and against packets on CUDA;
    and a scene without secondary rays, whose packets are also lit together, plain and adaptive,
    the rays counted too."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from scene_images import DATA, render_all

    one_by_one = render_all(device, packets=False)
    packets = dict(np.load(DATA)) if device == "cpu" else render_all(device, packets=True)
    assert sorted(one_by_one) == sorted(packets)
    for name, image in one_by_one.items():
        assert image.tobytes() == packets[name].tobytes(), name
    scene = warprt.load_scene(str(Path(__file__).parents[1] / "scenes" / "soft_shadows.toml"))
    scene = scene.replace(camera=dataclasses.replace(scene.camera, width=40, height=30)).with_settings(sampler="sobol")
    a, b = (warprt.Renderer(scene, device=device, packets=p) for p in (True, False))
    assert a.packets and not b.packets and not a.features.secondary and a.features == b.features
    for adaptive in (False, True):
        ra, rb = (r.render(spp=11, seed=5, progress=False, adaptive=adaptive) for r in (a, b))
        assert ra.image.tobytes() == rb.image.tobytes() and ra.rays == rb.rays, adaptive
        assert ra.image.mean() > 0.01


def test_camera_rays_one_by_one_give_the_packets_aovs_bit_for_bit(device):
    """Every AOV comes from the camera samples' own first hits, in packets (a shaded packet's lanes,
    CPU) or one by one (CUDA's path), in the same order: the same AOVs bit for bit, plain and
    adaptive (a scene without secondary rays, whose packets are lit together: the kernels of the
    test above)."""
    from pathlib import Path

    from warprt.aov import AOV_NAMES

    scene = warprt.load_scene(str(Path(__file__).parents[1] / "scenes" / "soft_shadows.toml"))
    scene = scene.replace(camera=dataclasses.replace(scene.camera, width=40, height=30)).with_settings(sampler="sobol")
    a, b = (warprt.Renderer(scene, device=device, packets=p) for p in (True, False))
    for adaptive in (False, True):
        ra, rb = (r.render(spp=11, seed=5, progress=False, adaptive=adaptive, aovs=AOV_NAMES) for r in (a, b))
        assert ra.image.tobytes() == rb.image.tobytes()
        for name in AOV_NAMES:
            assert ra.aovs[name].tobytes() == rb.aovs[name].tobytes(), (name, adaptive)
        assert len(np.unique(ra.aovs["object_id"])) >= 3 and 0 < ra.aovs["coverage"].mean() <= 1


def test_packets_are_the_cpus_and_one_by_one_cudas():
    from types import SimpleNamespace

    from warprt.integrator import packets_for

    assert packets_for(SimpleNamespace(is_cpu=True)) is True
    assert packets_for(SimpleNamespace(is_cpu=False)) is False
    assert warprt.Renderer(_scene(), device="cpu").packets is True
    assert warprt.Renderer(_scene(), device="cpu", packets=False).packets is False
    with pytest.raises(warprt.RenderError, match="packets must be True, False or None"):
        warprt.Renderer(_scene(), device="cpu", packets=1)

def test_mesh_instances_share_one_asset(device):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    shapes = tuple(warprt.Mesh(vertices=v.copy(), faces=f, transform=warprt.Transform(translate=(x, 0, 0)))
                   for x in range(3))
    other = warprt.Mesh(vertices=v * 2.0, faces=f)
    r = warprt.Renderer(_scene(shapes=shapes + (other,)), device=device)
    assert len(r.built.meshes) == 2  # equal arrays share one wp.Mesh, different ones do not
    assert r.built.data.n_inst == 4


def test_analytic_bvh_finds_the_same_hits_as_the_loop(device, monkeypatch):
    """Spheres, rectangles and disks through one BVH: the same image and hits as the loops (no
    two shapes here meet a ray at the same t, so the order of testing cannot matter)."""
    rng = np.random.default_rng(7)
    centers = rng.uniform(-1.5, 1.5, (40, 3))
    shapes = tuple(warprt.Sphere(center=tuple(c), radius=float(r), material="ball")
                   for c, r in zip(centers, rng.uniform(0.05, 0.35, 40)))
    shapes += tuple(warprt.Rectangle(corner=tuple(rng.uniform(-1.5, 1.5, 3)), edge1=tuple(rng.normal(0, 0.4, 3)),
                                     edge2=tuple(rng.normal(0, 0.4, 3)), material="ball") for _ in range(12))
    shapes += tuple(warprt.Disk(center=tuple(rng.uniform(-1.5, 1.5, 3)), normal=tuple(rng.normal(0, 1, 3)),
                                radius=float(rng.uniform(0.1, 0.4)), material="ball") for _ in range(12))
    shapes += (warprt.Plane(point=(0, -2, 0), material="floor"),)
    scene = _scene(shapes=shapes, camera=warprt.Camera(eye=(0, 0.5, 6), look_at=(0, 0, 0), width=32, height=24))
    with_bvh = warprt.Renderer(scene, device=device)
    assert with_bvh.built.analytic_bvh is not None
    assert_same_as_the_loops(scene, with_bvh, device, monkeypatch)


def assert_same_as_the_loops(scene, with_bvh, device, monkeypatch):
    """The image and the ray-query hits of ``with_bvh`` (built with the analytic BVH) equal those
    of a renderer built with the loops over each table."""
    monkeypatch.setattr(build_module, "ANALYTIC_BVH_MIN", 10 ** 9)
    loop = warprt.Renderer(scene, device=device)
    assert loop.built.analytic_bvh is None
    a = with_bvh.render(spp=2, progress=False).image
    b = loop.render(spp=2, progress=False).image
    assert a.tobytes() == b.tobytes()
    o, d = warprt.camera_rays(scene)
    ha, hb = warprt.trace_rays(with_bvh, o, d), warprt.trace_rays(loop, o, d)
    np.testing.assert_array_equal(ha["shape"], hb["shape"])
    np.testing.assert_array_equal(ha["t"], hb["t"])


@pytest.mark.parametrize("sampler", ["stratified", "sobol"])
def test_camera_rays_traced_in_packets_find_the_same_hits_as_one_by_one(device, monkeypatch, sampler):
    """With the analytic BVH, up to ``trace.PACKET`` camera rays of a pixel go through it
    together (``trace_packet``); without it each goes alone through the loops. Full packets,
    a partial one (11 spp), per-pixel counts (adaptive), rays with their own lens origins and
    times (moving spheres), every bounded kind, and exact ties (two coincident rectangles, two
    coincident disks: the lower row wins): the images equal the loops' bit for bit."""
    from warprt.trace import PACKET

    rng = np.random.default_rng(5)
    centers = rng.uniform(-1.5, 1.5, (24, 3))
    shapes = tuple(warprt.Sphere(center=tuple(c), radius=float(r), material="ball",
                                 center_end=tuple(c + (0.3, 0.0, 0.0)) if k % 3 == 0 else None)
                   for k, (c, r) in enumerate(zip(centers, rng.uniform(0.05, 0.3, 24))))
    tie = dict(corner=(-1.0, -0.9, -1.5), edge1=(2.0, 0.2, 0.0), edge2=(0.0, 0.3, 1.0))
    shapes += (warprt.Rectangle(**tie, material="ball"), warprt.Rectangle(**tie, material="floor"))
    disk_tie = dict(center=(0.9, 0.7, -0.8), normal=(0.2, 0.1, 1.0), radius=0.45)  # lanes test disks one by one
    shapes += (warprt.Disk(**disk_tie, material="floor"), warprt.Disk(**disk_tie, material="ball"))
    shapes += tuple(warprt.Rectangle(corner=tuple(rng.uniform(-1.5, 1.5, 3)), edge1=tuple(rng.normal(0, 0.4, 3)),
                                     edge2=tuple(rng.normal(0, 0.4, 3)), material="ball") for _ in range(6))
    shapes += tuple(warprt.Disk(center=tuple(rng.uniform(-1.5, 1.5, 3)), normal=tuple(rng.normal(0, 1, 3)),
                                radius=float(rng.uniform(0.1, 0.4)), material="floor") for _ in range(4))
    shapes += (warprt.Box(center=(0.8, -1.2, 0.5), size=(0.5, 0.4, 0.6), material="floor"),
               warprt.Plane(point=(0, -2, 0), material="floor"))
    scene = _scene(shapes=shapes, camera=warprt.Camera(eye=(0, 0.5, 6), look_at=(0, 0, 0), width=24, height=18,
                                                       aperture=0.08, focus_distance=6.0)).with_settings(sampler=sampler)
    assert warprt.Renderer(scene, device=device).features.key == "lens+motion+solids+analytic_bvh"
    # both on the all-features kernel the suite compiles anyway: without the tree its camera rays
    # go one by one (the packet code runs only where the scene has an analytic BVH)
    packets = warprt.Renderer(scene, device=device, features=Features.full())
    assert packets.built.analytic_bvh is not None
    monkeypatch.setattr(build_module, "ANALYTIC_BVH_MIN", 10 ** 9)
    loops = warprt.Renderer(scene, device=device, features=Features.full())
    assert loops.built.analytic_bvh is None
    for spp, adaptive in ((PACKET, False), (11, False), (8, True)):
        a = packets.render(spp=spp, seed=3, progress=False, adaptive=adaptive).image
        b = loops.render(spp=spp, seed=3, progress=False, adaptive=adaptive).image
        assert a.tobytes() == b.tobytes(), (spp, adaptive)


@pytest.mark.parametrize("sampler", ["stratified", "sobol"])
def test_camera_rays_through_meshes_in_mesh_packets_find_the_same_hits_as_one_by_one(device, monkeypatch, sampler):
    """With meshes, up to ``trace.PACKET`` camera rays also go through each mesh's tree together
    (``trace.mesh_packet``; on the CPU ``accel.mesh_tree_packet``), each bounded by its own
    analytic hit; a packet takes the next pixels' samples too where a pixel has fewer left. A
    render whose passes are one sample each and whose threads take one pixel each traces every
    camera ray alone; the packets' images equal it bit for bit, with a full and a part packet
    per pixel, with adaptive sampling's per-pixel counts (packets over several pixels), and with
    one-sample passes over whole rows (packets of 8 pixels): two meshes (one posed and moving),
    a sphere in front of one, a plane, rays with their own lens origins and times."""
    from warprt.trace import PACKET

    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24, endpoint=False), np.linspace(0, 2 * np.pi, 12, endpoint=False),
                       indexing="ij")
    r = 0.35 * (1.0 + 0.1 * np.sin(5 * u) * np.sin(3 * v))
    verts = np.stack([(0.8 + r * np.cos(v)) * np.cos(u), r * np.sin(v), (0.8 + r * np.cos(v)) * np.sin(u)], -1)
    i, j = np.meshgrid(np.arange(24), np.arange(12), indexing="ij")
    a, b = i * 12 + j, ((i + 1) % 24) * 12 + j
    c, d = ((i + 1) % 24) * 12 + (j + 1) % 12, i * 12 + (j + 1) % 12
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    torus = warprt.Mesh(vertices=verts.reshape(-1, 3), faces=faces, material="ball")
    from warprt.scene.transform import Transform

    posed = warprt.Mesh(vertices=verts.reshape(-1, 3), faces=faces, material="floor",
                        transform=Transform(translate=(1.3, 0.4, -0.5), rotate=(40, 0, 10), scale=(0.6, 0.6, 0.6)),
                        transform_end=Transform(translate=(1.5, 0.4, -0.5), rotate=(50, 0, 10), scale=(0.6, 0.6, 0.6)))
    shapes = (torus, posed, warprt.Sphere(center=(0.35, 1.15, 2.1), radius=0.2, material="floor"),
              warprt.Plane(point=(0, -0.5, 0), material="floor"))
    scene = _scene(shapes=shapes, camera=warprt.Camera(eye=(0.4, 1.8, 3.2), look_at=(0.2, 0, 0), width=24, height=18,
                                                       aperture=0.05, focus_distance=3.5)).with_settings(sampler=sampler)
    ren = warprt.Renderer(scene, device=device)
    assert ren.features.meshes and ren.built.analytic_bvh is None
    spp = PACKET + 3  # one full packet and a part one too small for a packet, after the first pass
    a = ren.render(spp=spp, seed=4, progress=False).image
    a_rows = ren.render(spp=spp, seed=4, progress=False, pass_spp=1).image
    a_adaptive = ren.render(spp=8, seed=4, progress=False, adaptive=True).image
    monkeypatch.setattr(render_module, "pixels_per_thread", lambda dev, width: 1)
    alone = warprt.Renderer(scene, device=device)  # (its recorded launches made with one pixel a thread)
    b = alone.render(spp=spp, seed=4, progress=False, pass_spp=1).image
    b_adaptive = alone.render(spp=8, seed=4, progress=False, adaptive=True, pass_spp=1).image
    assert a.tobytes() == b.tobytes()
    assert a_rows.tobytes() == b.tobytes()
    assert a_adaptive.tobytes() == b_adaptive.tobytes()



def test_a_packets_camera_rays_equal_each_made_alone(device, monkeypatch):
    """A camera packet's rays, at rest, are made for its 8 lanes at once (``camera.camera_packet``
    for a pinhole, ``camera.lens_packet`` for a thin lens, in the frame ``camera_frame`` gives once
    per thread); a moving camera, with or without a lens, and a scene whose objects move (time
    sampled) take each lane's ``camera_ray``.
    Each renders the same image bit for bit as one-sample passes with one pixel a thread, where
    every camera ray is made alone: full packets, a part packet and packets over several pixels
    (adaptive counts), with Sobol points (the packet's path) and stratified ones."""
    from warprt.trace import PACKET

    cams = dict(pinhole=warprt.Camera(eye=(0.3, 1.1, 4), look_at=(0, 0.4, 0), width=20, height=14, fov=50.0),
                lens=warprt.Camera(eye=(0.3, 1.1, 4), look_at=(0, 0.4, 0), width=20, height=14, aperture=0.1),
                moving=warprt.Camera(eye=(0.3, 1.1, 4), look_at=(0, 0.4, 0), width=20, height=14,
                                     eye_end=(0.6, 1.1, 4)),
                moving_lens=warprt.Camera(eye=(0.3, 1.1, 4), look_at=(0, 0.4, 0), width=20, height=14, aperture=0.1,
                                          eye_end=(0.6, 1.1, 4)))
    scenes = {k: _scene(camera=c) for k, c in cams.items()}
    scenes["objects moving"] = _scene(camera=cams["pinhole"], shapes=(
        warprt.Plane(material="floor"),
        warprt.Sphere(center=(0, 0.5, 0), radius=0.5, material="ball", center_end=(0.3, 0.5, 0))))
    images = {}
    for alone in (False, True):
        if alone:
            monkeypatch.setattr(render_module, "pixels_per_thread", lambda dev, width: 1)
        for name, scene in scenes.items():
            for sampler in ("sobol", "stratified"):
                ren = warprt.Renderer(scene.with_settings(sampler=sampler), device=device, features=Features.full())
                for spp, adaptive in ((PACKET, False), (PACKET + 3, False), (8, True)):
                    img = ren.render(spp=spp, seed=6, progress=False, adaptive=adaptive,
                                     pass_spp=1 if alone else None).image
                    images[alone, name, sampler, spp, adaptive] = img.tobytes()
    for key, img in images.items():
        if not key[0]:
            assert img == images[(True,) + key[1:]], key[1:]


@pytest.mark.parametrize("sampler", ["stratified", "sobol"])
def test_area_lights_drawn_for_a_packet_equal_each_lane_drawn_alone(device, monkeypatch, sampler):
    """With camera packets and area lights (and no secondary rays) a packet's shading points draw
    each area light together (``lights.area_lights_packet``; on the CPU a rectangle's draws as
    clang vectors, ``shapes.rect_draw_packet``). Every lane's sample must be the one it gets
    alone, bit for bit: rectangles near enough to be drawn by solid angle (which the scalar draw
    takes) and farther ones, a sheared one, lights below some points' horizon and behind others,
    a sphere and a disk light, a rectangle light flush with a ceiling, one to four samples per
    light, specular materials (and a coloured Lambertian one), both light-sampling modes, full and
    part packets, packets over several pixels (adaptive counts), and with Sobol points drawn for
    the 8 lanes at once (``sampling.sobol_packet``, and ``sobol_split_draw`` for the light with
    four samples, drawn in quadrant order)."""
    from warprt.trace import PACKET

    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16, endpoint=False), np.linspace(0, 2 * np.pi, 8, endpoint=False),
                       indexing="ij")
    verts = np.stack([(0.6 + 0.25 * np.cos(v)) * np.cos(u), 0.25 + 0.25 * np.sin(v), (0.6 + 0.25 * np.cos(v)) * np.sin(u)],
                     -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(16), np.arange(8), indexing="ij")
    a, b = i * 8 + j, ((i + 1) % 16) * 8 + j
    c, d = ((i + 1) % 16) * 8 + (j + 1) % 8, i * 8 + (j + 1) % 8
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    shapes = (warprt.Plane(material="floor"), warprt.Mesh(vertices=verts, faces=faces, material="ball"),
              warprt.Sphere(center=(-1.0, 0.3, 0.6), radius=0.3, material="shiny"),
              warprt.Rectangle(corner=(0.9, 0.0, -1.2), edge1=(0.0, 0.8, 0.0), edge2=(0.5, 0.0, 0.6), material="wall"),
              warprt.Plane(point=(0.0, 3.5, 0.0), normal=(0.0, -1.0, 0.0), material="floor"))  # (a ceiling)
    lights = (
        # near the floor: drawn by solid angle below it, by the cosine warp farther off
        # four samples: with Sobol drawn in quadrant order (sampling.sobol_split_draw)
        warprt.RectLight(corner=(-2.2, 0.45, -1.0), edge1=(1.2, 0.0, 0.0), edge2=(0.0, 0.0, 0.8), radiance=(2.0, 1.8, 1.5),
                         samples=4),
        # far, tilted, and sheared (never by solid angle), three samples
        warprt.RectLight(corner=(2.0, 2.5, -1.0), edge1=(0.0, 0.6, 0.6), edge2=(0.4, -0.6, 0.3), radiance=(1.5, 1.5, 2.0),
                         samples=3),
        warprt.SphereLight(center=(-1.5, 1.5, 1.0), radius=0.2, radiance=(3.0, 3.0, 3.0)),
        warprt.DiskLight(center=(0.0, 2.0, 1.5), normal=(0.0, -1.0, -0.3), radius=0.3, radiance=(2.0, 2.0, 2.0),
                         samples=2),
        warprt.PointLight(position=(1.0, 2.0, 2.0), intensity=0.5),
        # flush with the ceiling: its shadow rays end on the ceiling's plane, short by the stop
        warprt.RectLight(corner=(-0.5, 3.5, -0.5), edge1=(1.0, 0.0, 0.0), edge2=(0.0, 0.0, 1.0), radiance=(1.5, 1.5, 1.5),
                         samples=2),
    )
    # (the wall a coloured Lambertian: packets of such lanes take their colours at once, lights.diffuse_lanes)
    materials = {"floor": warprt.Material(kd=0.7), "ball": warprt.Material(kd=(0.8, 0.2, 0.1), ks=0.4, p=40),
                 "shiny": warprt.Material(kd=0.3, ks=0.6, p=200), "wall": warprt.Material(kd=(0.2, 0.5, 0.7))}
    camera = warprt.Camera(eye=(0.3, 1.6, 3.0), look_at=(0.0, 0.3, 0.0), width=24, height=18)
    spp = PACKET + 3  # a full packet and a part one per pixel
    for mode in ("cosine", "uniform"):
        scene = _scene(shapes=shapes, lights=lights, materials=materials, camera=camera).with_settings(
            light_sampling=mode, sampler=sampler)
        ren = warprt.Renderer(scene, device=device, packets=True)  # CUDA's default is one by one
        assert ren.packets and ren.features.area_lights and not ren.features.secondary
        ra = ren.render(spp=spp, seed=4, progress=False)
        a = ra.image
        a_adaptive = ren.render(spp=8, seed=4, progress=False, adaptive=True).image
        with monkeypatch.context() as m:
            m.setattr(render_module, "pixels_per_thread", lambda dev, width: 1)
            # every camera sample alone: one a pass and thread
            alone = warprt.Renderer(scene, device=device, packets=True)
            rb = alone.render(spp=spp, seed=4, progress=False, pass_spp=1)
            b = rb.image
            b_adaptive = alone.render(spp=8, seed=4, progress=False, adaptive=True, pass_spp=1).image
        assert a.tobytes() == b.tobytes(), mode
        assert a_adaptive.tobytes() == b_adaptive.tobytes(), mode
        assert ra.rays == rb.rays, mode  # the shadow rays counted too
        assert a.min() >= 0.0 and a.mean() > 0.05


def _point_lights_scene(sampler: str, extra: tuple = ()) -> warprt.Scene:
    """Point lights over spheres (half of them moving), a posed mesh, a box, a disk and a
    rectangle casting shadows on two planes, with ``extra`` shapes: the scene of
    ``test_point_lights_lit_for_a_packet_equal_each_lane_lit_alone``."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16, endpoint=False), np.linspace(0, 2 * np.pi, 8, endpoint=False),
                       indexing="ij")
    verts = np.stack([(0.5 + 0.2 * np.cos(v)) * np.cos(u), 0.2 * np.sin(v), (0.5 + 0.2 * np.cos(v)) * np.sin(u)],
                     -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(16), np.arange(8), indexing="ij")
    a, b = i * 8 + j, ((i + 1) % 16) * 8 + j
    c, d = ((i + 1) % 16) * 8 + (j + 1) % 8, i * 8 + (j + 1) % 8
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    from warprt.scene.transform import Transform

    rng = np.random.default_rng(11)
    shapes = (warprt.Plane(material="floor"), warprt.Plane(point=(-1.6, 0.0, 0.0), normal=(1.0, 0.0, 0.0), material="floor"),
              warprt.Mesh(vertices=verts, faces=faces, material="ball",
                          transform=Transform(translate=(0.9, 0.45, -0.3), rotate=(30, 0, 15))),
              warprt.Box(center=(-0.9, 0.25, 0.4), size=(0.4, 0.5, 0.3), material="shiny"),
              warprt.Disk(center=(0.2, 1.2, 0.8), normal=(0.2, 1.0, 0.1), radius=0.25, material="floor"),
              warprt.Rectangle(corner=(-0.2, 0.9, -0.8), edge1=(0.6, 0.1, 0.0), edge2=(0.0, 0.05, 0.5),
                               material="shiny"))
    shapes += tuple(warprt.Sphere(center=tuple(q), radius=float(r), material="ball",
                                  center_end=tuple(q + (0.25, 0.1, 0.0)) if k % 2 == 0 else None)
                    for k, (q, r) in enumerate(zip(rng.uniform((-1.5, 0.1, -1.0), (1.5, 1.0, 1.0), (6, 3)),
                                                   rng.uniform(0.08, 0.2, 6))))
    lights = (warprt.PointLight(position=(1.0, 2.5, 2.0), intensity=4.0, falloff="inverse_square"),
              warprt.PointLight(position=(-2.2, 1.8, -0.5), intensity=(0.3, 0.25, 0.2)),  # behind the wall
              warprt.DirectionalLight(direction=(0.3, -1.0, -0.4), intensity=(0.3, 0.3, 0.35)),
              warprt.PointLight(position=(0.0, 1e-7, 0.0), intensity=0.2))  # on the floor: no shadow ray
    materials = {"floor": warprt.Material(kd=0.7), "ball": warprt.Material(kd=(0.8, 0.2, 0.1), ks=0.4, p=40),
                 "shiny": warprt.Material(kd=0.3, ks=0.6, p=200)}
    camera = warprt.Camera(eye=(0.3, 1.8, 3.2), look_at=(0.0, 0.3, 0.0), width=24, height=18, shutter=(0.0, 1.0))
    return _scene(shapes=shapes + extra, lights=lights, materials=materials,
                  camera=camera).with_settings(sampler=sampler)


@pytest.mark.parametrize("sampler, bvh", [("sobol", True), ("sobol", False), ("stratified", True)])
def test_point_lights_lit_for_a_packet_equal_each_lane_lit_alone(device, monkeypatch, sampler, bvh):
    """Without secondary rays a packet's shading points also take the point and directional lights
    together (``lights.point_lights_packet``: on the CPU each light's directions, n·l, n·h and
    shadow rays for the 8 lanes as clang vectors), and their shadow rays go together
    (``trace.occluded_packet``: spheres, planes, rectangles, the analytic BVH and the mesh
    instances' boxes for all lanes at once, disks, solids and triangles lane by lane). Every
    lane's light must be the one it gets alone, bit for bit, with and without the analytic BVH:
    an inverse-square, an unattenuated (behind a wall: planes cast shadows too) and a directional
    light, a light just above a surface (shadow rays shorter than the stop), Blinn-Phong lobes,
    moving spheres (their centres at each lane's time), a posed mesh, a box, disks and rectangles
    that cast shadows, full and part packets, packets over several pixels (adaptive counts)."""
    from warprt.trace import PACKET

    scene = _point_lights_scene(sampler)
    if not bvh:
        monkeypatch.setattr(build_module, "ANALYTIC_BVH_MIN", 10 ** 9)
    ren = warprt.Renderer(scene, device=device, packets=True)  # CUDA's default is one by one
    assert ren.packets and not ren.features.secondary and not ren.features.area_lights
    assert (ren.built.analytic_bvh is not None) == bvh
    spp = PACKET + 3  # a full packet and a part one per pixel
    a = ren.render(spp=spp, seed=4, progress=False).image
    a_adaptive = ren.render(spp=8, seed=4, progress=False, adaptive=True).image
    monkeypatch.setattr(render_module, "pixels_per_thread", lambda dev, width: 1)
    alone = warprt.Renderer(scene, device=device, packets=True)  # every camera sample alone: one a pass and thread
    b = alone.render(spp=spp, seed=4, progress=False, pass_spp=1).image
    b_adaptive = alone.render(spp=8, seed=4, progress=False, adaptive=True, pass_spp=1).image
    assert a.tobytes() == b.tobytes()
    assert a_adaptive.tobytes() == b_adaptive.tobytes()
    assert a.min() >= 0.0 and a.mean() > 0.05


def test_light_buffers_answer_as_the_bvh_walk(monkeypatch):
    """On the CPU a point light gets a light buffer (``accel.light_buffer``): a camera packet's
    shadow rays towards it test the primitives listed in their origin's cell instead of walking
    the analytic BVH. Rendered with and without the buffers (``accel.LB_MAX_ITEMS`` 0: every ray
    walks), the images are the same bit for bit, with the scene of the test above, long bars on
    the floor (boxed in pieces) and one bar above it, and a small sphere beside a light, which cuts
    that light's reach to a part of the scene (its farther rays walk). A directional light has
    none."""
    bars = tuple(warprt.Rectangle(corner=(-1.5, 0.002, 0.9 - 0.35 * k), edge1=(3.0, 0.0, -0.4), edge2=(0.02, 0.0, 0.15),
                                  material="shiny") for k in range(5))
    extra = bars + (warprt.Rectangle(corner=(-1.2, 0.7, 0.9), edge1=(1.5, 0.0, -0.5), edge2=(0.03, 0.02, 0.12),
                                     material="floor"),
                    warprt.Sphere(center=(1.0, 2.476, 2.0), radius=0.02, material="ball"))
    scene = _point_lights_scene("sobol", extra)
    ren = warprt.Renderer(scene, device="cpu", packets=True)
    rec = ren.built.data.plights.numpy()
    assert list(rec["lb_cell0"] >= 0) == [True, True, False, True]  # (the third: directional)
    assert 2.5 < rec["lb_reach"][0] < 5.0  # (the light is 2.5 above the floor)
    monkeypatch.setattr(accel, "LB_MAX_ITEMS", 0)
    walk = warprt.Renderer(scene, device="cpu", packets=True)
    assert (walk.built.data.plights.numpy()["lb_cell0"] == -1).all()
    for spp, adaptive in ((11, False), (8, True)):
        a = ren.render(spp=spp, seed=4, progress=False, adaptive=adaptive).image
        b = walk.render(spp=spp, seed=4, progress=False, adaptive=adaptive).image
        assert a.tobytes() == b.tobytes()
    assert a.min() >= 0.0 and a.mean() > 0.05


def test_long_rectangles_boxed_in_pieces_find_the_same_hits_and_shadows(device, monkeypatch):
    """Long thin opaque bars tilted off the axes go into the BVH as pieces
    (``shapes.rect_pieces``); a transparent bar stays whole, so its shadow counts one crossing.
    The image and the hits equal the loop's, and the pieces cover every bar."""
    from warprt.shapes import RECT_MAX_PIECES, rect_pieces

    rng = np.random.default_rng(3)
    shapes = []
    for k in range(20):
        a = math.radians(8.0 + 3.0 * k)
        e1 = np.array([math.cos(a), 0.0, -math.sin(a)]) * 6.0
        e2 = np.array([math.sin(a), 0.0, math.cos(a)]) * 0.06
        shapes.append(warprt.Rectangle(corner=(-3.0 + 0.3 * k, 0.01 * (k + 1), 1.0 - 0.2 * k), edge1=tuple(e1),
                                       edge2=tuple(e2), material="glass" if k == 7 else "ball"))
    shapes.append(warprt.Rectangle(corner=(-2.0, 0.6, -1.0), edge1=(5.0, 0.3, 0.0), edge2=(0.0, 0.0, 0.08),
                                   material="glass"))
    shapes.append(warprt.Plane(point=(0, 0, 0), material="floor"))
    scene = _scene(shapes=tuple(shapes), camera=warprt.Camera(eye=(0, 2.5, 4), look_at=(0, 0, -1), width=40,
                                                              height=30),
                   materials={"ball": warprt.Material(kd=0.7), "floor": warprt.Material(kd=0.5),
                              "glass": warprt.Material(kd=0.1, transparency=0.6)})
    for s in shapes[:-1]:
        row = {"c": s.corner, "e1": s.edge1, "e2": s.edge2}
        pieces = rect_pieces(row)
        assert 1 <= len(pieces) <= RECT_MAX_PIECES
        uv = rng.random((500, 2))
        pts = np.asarray(s.corner) + uv[:, :1] * np.asarray(s.edge1) + uv[:, 1:] * np.asarray(s.edge2)
        inside = np.zeros(len(pts), bool)
        for lo, hi in pieces:
            inside |= ((pts >= lo - 1e-12) & (pts <= hi + 1e-12)).all(axis=1)
        assert inside.all()
    assert len(rect_pieces({"c": shapes[0].corner, "e1": shapes[0].edge1, "e2": shapes[0].edge2})) == RECT_MAX_PIECES
    with_bvh = warprt.Renderer(scene, device=device)
    n_bvh_prims = with_bvh.built.data.bvh_prims.shape[0]
    assert n_bvh_prims == 19 * RECT_MAX_PIECES + 2  # two transparent bars whole
    assert_same_as_the_loops(scene, with_bvh, device, monkeypatch)
