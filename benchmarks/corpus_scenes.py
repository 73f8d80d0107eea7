"""The corpus's scenes: generated in code with warprt's public API only, one builder per scene.

Every builder takes ``(width, height)`` (the corpus's own size when None) and returns a
``warprt.Scene`` with no render option set (sampler, light samples, adaptive sampling: the
renderer's defaults decide), Lambert materials (plus perfect mirrors and exact-Fresnel glass),
no ambient light and inverse-square point lights, so that Mitsuba 3 renders the same physics
(``benchmarks.mitsuba_export``). Random layouts come from fixed seeds: a scene is the same on
every run. The registry, its kinds and its training/validation split are in
``benchmarks.corpus``.
"""

from __future__ import annotations

import math

import numpy as np

import warprt

# --- pieces ------------------------------------------------------------------------------------------


def lambert(kd) -> warprt.Material:
    return warprt.Material(kd=kd, ka=0.0)


MIRROR = warprt.Material(kd=0.0, ka=0.0, mirror=0.9)
GLASS = warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=1.5, fresnel="exact")


def point_light(position, intensity_w_per_sr) -> warprt.PointLight:
    """A point light of intensity I (W/sr, Mitsuba's convention: E = I cos / d^2). warprt's point
    light has no 1/pi in its shading (kd * I' * cos), so I' = I/pi is the same light."""
    i = np.broadcast_to(np.asarray(intensity_w_per_sr, dtype=float), (3,))
    return warprt.PointLight(position=position, intensity=tuple(float(c) / math.pi for c in i),
                             falloff="inverse_square")


def sun(direction, irradiance) -> warprt.DirectionalLight:
    """A directional light of irradiance E (W/m^2 on a surface facing it); warprt's directional
    light shades kd * I * cos, so I = E/pi."""
    e = np.broadcast_to(np.asarray(irradiance, dtype=float), (3,))
    return warprt.DirectionalLight(direction=direction, intensity=tuple(float(c) / math.pi for c in e))


def ceiling_light(center, size_x, size_z, radiance) -> warprt.RectLight:
    """A rectangle light in the plane y = center[1], facing down."""
    cx, cy, cz = center
    # edge1 x edge2 = (size_x, 0, 0) x (0, 0, size_z) = (0, -size_x size_z, 0): down
    return warprt.RectLight(corner=(cx - size_x / 2, cy, cz - size_z / 2), edge1=(size_x, 0.0, 0.0),
                            edge2=(0.0, 0.0, size_z), radiance=radiance)


def facing_light(center, normal, width, height, radiance) -> warprt.RectLight:
    """A rectangle light centred on ``center`` emitting along ``normal``."""
    n = np.asarray(normal, float)
    n /= np.linalg.norm(n)
    a = np.cross([0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0], n)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)  # a x b = n
    e1, e2 = width * a, height * b
    corner = np.asarray(center, float) - e1 / 2 - e2 / 2
    return warprt.RectLight(corner=tuple(corner), edge1=tuple(e1), edge2=tuple(e2), radiance=radiance)


def ground(material: str = "ground") -> warprt.Plane:
    """The ground y = 0 (Mitsuba: a square of half side 100, see mitsuba_export)."""
    return warprt.Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), material=material)


def room(x0, x1, y1, z0, z1, walls=("white", "red", "green", "white", "white", "white")):
    """Six inward-facing rectangles closing the box [x0, x1] x [0, y1] x [z0, z1]: floor, left,
    right, back (z0), front (z1), ceiling, with the given material names."""
    floor, left, right, back, front, ceil = walls
    dx, dy, dz = x1 - x0, y1, z1 - z0
    return (
        warprt.Rectangle(corner=(x0, 0.0, z0), edge1=(0.0, 0.0, dz), edge2=(dx, 0.0, 0.0), material=floor),
        warprt.Rectangle(corner=(x0, 0.0, z0), edge1=(0.0, dy, 0.0), edge2=(0.0, 0.0, dz), material=left),
        warprt.Rectangle(corner=(x1, 0.0, z0), edge1=(0.0, 0.0, dz), edge2=(0.0, dy, 0.0), material=right),
        warprt.Rectangle(corner=(x0, 0.0, z0), edge1=(dx, 0.0, 0.0), edge2=(0.0, dy, 0.0), material=back),
        warprt.Rectangle(corner=(x0, 0.0, z1), edge1=(0.0, dy, 0.0), edge2=(dx, 0.0, 0.0), material=front),
        warprt.Rectangle(corner=(x0, y1, z0), edge1=(dx, 0.0, 0.0), edge2=(0.0, 0.0, dz), material=ceil),
    )


def camera(eye, look_at, fov, size, **kw) -> warprt.Camera:
    return warprt.Camera(eye=eye, look_at=look_at, fov=fov, width=size[0], height=size[1], **kw)


def yaw(deg: float) -> warprt.Transform:
    return warprt.Transform(rotate=(0.0, deg, 0.0))


def posed(translate, rotate=(0.0, 0.0, 0.0), scale=1.0) -> warprt.Transform:
    return warprt.Transform(translate=translate, rotate=rotate, scale=scale)


# --- meshes ----------------------------------------------------------------------------------------------


def torus(n_major: int, n_minor: int, major: float, minor: float, bumps: float = 0.0,
          waves: tuple[int, int] = (24, 12)):
    """A torus around the y axis, (n_major x n_minor) quads of 2 triangles, optional bumps on the
    tube radius (``waves``: their count around the ring and around the tube); closed,
    outward-facing, consistently wound. (The benchmarks' and the tests' one torus.)"""
    u = np.arange(n_major) * (2 * np.pi / n_major)
    v = np.arange(n_minor) * (2 * np.pi / n_minor)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = minor * (1.0 + bumps * np.sin(waves[0] * uu) * np.sin(waves[1] * vv))
    x = (major + r * np.cos(vv)) * np.cos(uu)
    z = (major + r * np.cos(vv)) * np.sin(uu)
    y = r * np.sin(vv)
    vertices = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    return vertices, faces


def icosphere(subdivisions: int, radius: float = 1.0):
    """20 * 4^subdivisions triangles."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def displaced_sphere(subdivisions: int, radius: float, amplitude: float, seed: int = 0, waves: int = 12):
    """An icosphere whose radius varies by a sum of ``waves`` random plane waves (a rock, a
    blob): closed, star-shaped."""
    v, f = icosphere(subdivisions, 1.0)
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(waves, 3)) * rng.uniform(1.5, 6.0, size=(waves, 1))
    phase = rng.uniform(0, 2 * np.pi, waves)
    amp = rng.uniform(0.3, 1.0, waves) / np.arange(1, waves + 1) ** 0.5
    d = (np.sin(v @ k.T + phase) * amp).sum(axis=1)
    d /= np.abs(d).max()
    return v * (radius * (1.0 + amplitude * d))[:, None], f


def terrain(n: int, size: float, height: float, seed: int = 0):
    """An n x n grid of quads (2 n^2 triangles) over [-size/2, size/2]^2, heights from a sum of
    random waves."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-size / 2, size / 2, n + 1)
    xx, zz = np.meshgrid(g, g, indexing="ij")
    y = np.zeros_like(xx)
    for octave in range(6):
        freq = 2 * np.pi * (2 ** octave) / size * rng.uniform(0.8, 1.3)
        ang = rng.uniform(0, np.pi, 2)
        for a, p in zip(ang, rng.uniform(0, 2 * np.pi, 2)):
            y += np.sin(freq * (np.cos(a) * xx + np.sin(a) * zz) + p) / (1.8 ** octave)
    y = (y - y.min()) / (y.max() - y.min()) * height
    vertices = np.stack([xx, y, zz], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = i * (n + 1) + j
    b = (i + 1) * (n + 1) + j
    c = (i + 1) * (n + 1) + j + 1
    d = i * (n + 1) + j + 1
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    return vertices, faces


def cone(n: int, radius: float, height: float):
    """A closed cone (apex up, base at y = 0) of 2n triangles."""
    ang = np.arange(n) * (2 * np.pi / n)
    ring = np.stack([radius * np.cos(ang), np.zeros(n), radius * np.sin(ang)], axis=1)
    v = np.concatenate([ring, [[0.0, height, 0.0], [0.0, 0.0, 0.0]]])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.stack([i, np.full(n, n), j], axis=1)  # outward: ring i, apex, ring i+1
    base = np.stack([i, j, np.full(n, n + 1)], axis=1)
    return v, np.concatenate([side, base])


def mesh(vf, material, transform=None, transform_end=None) -> warprt.Mesh:
    v, f = vf
    return warprt.Mesh(vertices=v, faces=f, material=material, transform=transform, transform_end=transform_end)


def tri_count(scene: warprt.Scene) -> int:
    return int(sum(len(s.faces) for s in scene.shapes if isinstance(s, warprt.Mesh) and s.faces is not None))


def _size(width, height, default):
    return (width or default[0], height or default[1])


# --- rooms lit from the ceiling --------------------------------------------------------------------------


def room_two_boxes(width=None, height=None):
    """A closed room 2 x 2 x 3.2 (red left wall, green right), a ceiling panel light above the
    camera (out of its view), a tall and a short box; the camera inside, by the front wall."""
    size = _size(width, height, (256, 256))
    shapes = room(-1, 1, 2, -1, 2.2) + (
        warprt.Box(center=(0, 0, 0), size=(0.55, 1.2, 0.55), material="box",
                   transform=posed((-0.35, 0.6, -0.3), (0, 22, 0))),
        warprt.Box(center=(0, 0, 0), size=(0.6, 0.6, 0.6), material="box",
                   transform=posed((0.38, 0.3, 0.25), (0, -17, 0))),
    )
    return warprt.Scene(
        camera=camera((0.0, 1.0, 2.1), (0.0, 0.8, -1.0), 55.0, size), shapes=shapes,
        materials={"white": lambert(0.72), "red": lambert((0.65, 0.08, 0.06)), "green": lambert((0.12, 0.55, 0.1)),
                   "box": lambert(0.72)},
        lights=(ceiling_light((0.0, 1.985, 1.2), 0.6, 0.5, 14.0),))


def room_shelves(width=None, height=None):
    """A storeroom 6 x 3 x 5 with two ceiling panels: shelves of crates, a barrel (cylinder), a
    capsule post, crates on the floor; seen from a corner."""
    size = _size(width, height, (320, 240))
    rng = np.random.default_rng(11)
    shapes = list(room(-3, 3, 3, -2.5, 2.5, walls=("floor", "wall", "wall", "wall", "wall", "white")))
    for level in (0.6, 1.3, 2.0):  # two shelves along the back wall
        shapes.append(warprt.Box(center=(-1.2, level, -2.1), size=(2.8, 0.06, 0.7), material="wood"))
        for k in range(5):
            w = rng.uniform(0.25, 0.45)
            h = rng.uniform(0.2, 0.45)
            shapes.append(warprt.Box(center=(-2.3 + 0.55 * k, level + 0.03 + h / 2, -2.1 + rng.uniform(-0.1, 0.1)),
                                     size=(w, h, 0.4), material=("crate", "blue")[k % 2]))
    for x, z, a in ((1.0, -1.2, 15), (1.6, -0.4, -30), (1.2, 0.5, 40), (0.2, -0.3, 5)):
        shapes.append(warprt.Box(center=(0, 0, 0), size=(0.6, 0.5, 0.6), material="crate",
                                 transform=posed((x, 0.25, z), (0, a, 0))))
    shapes.append(warprt.Cylinder(start=(2.2, 0.0, -1.8), end=(2.2, 0.9, -1.8), radius=0.3, material="blue"))
    shapes.append(warprt.Capsule(start=(-0.6, 0.35, 1.0), end=(-0.6, 2.65, 1.0), radius=0.12, material="white"))
    return warprt.Scene(
        camera=camera((2.7, 2.2, 2.2), (-0.6, 0.8, -1.2), 60.0, size), shapes=tuple(shapes),
        materials={"floor": lambert(0.45), "wall": lambert((0.75, 0.72, 0.66)), "white": lambert(0.8),
                   "wood": lambert((0.55, 0.38, 0.22)), "crate": lambert((0.7, 0.55, 0.3)),
                   "blue": lambert((0.2, 0.35, 0.7))},
        lights=(ceiling_light((0.6, 2.99, 1.6), 1.2, 0.5, 9.0), ceiling_light((2.2, 2.99, -0.4), 0.5, 1.2, 9.0)))


# --- many instances of a few meshes -------------------------------------------------------------------------


def instances_tori(width=None, height=None):
    """48 instances of one 3,072-triangle torus on a 8 x 6 grid, turned at random, a third of
    them stretched (non-uniform scale), under a rectangle light."""
    size = _size(width, height, (256, 256))
    vf = torus(48, 32, major=0.3, minor=0.11)
    rng = np.random.default_rng(3)
    shapes = [ground()]
    for i in range(8):
        for j in range(6):
            scale = (1.0, 1.0, 1.0) if (i + j) % 3 else tuple(rng.uniform(0.6, 1.5, 3))
            rot = (rng.uniform(-70, 70), rng.uniform(0, 360), rng.uniform(-30, 30))
            t = posed((-2.1 + 0.6 * i, 0.42, -2.4 + 0.6 * j), rot, scale)
            shapes.append(mesh(vf, ("gold", "teal")[(i * 6 + j) % 2], t))
    return warprt.Scene(
        camera=camera((0.0, 3.2, 3.6), (0.0, 0.2, -0.9), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.55), "gold": lambert((0.8, 0.6, 0.25)), "teal": lambert((0.2, 0.6, 0.6))},
        lights=(ceiling_light((0.5, 4.0, 0.0), 2.5, 2.0, 4.0),))


def instances_mixed(width=None, height=None):
    """200 instances of three meshes (a 1,280-triangle rock, a 2,048-triangle torus, a
    128-triangle cone), each turned at random and scaled non-uniformly (0.5-1.8 per axis),
    scattered over the ground under a rectangle light and a sphere light."""
    size = _size(width, height, (320, 240))
    rng = np.random.default_rng(5)
    meshes = {"rock": displaced_sphere(3, 0.25, 0.25, seed=2), "torus": torus(64, 16, 0.25, 0.08),
              "cone": cone(64, 0.2, 0.6)}
    names = list(meshes)
    shapes = [ground()]
    for k in range(200):
        name = names[k % 3]
        x, z = rng.uniform(-4, 4), rng.uniform(-5, 1.5)
        s = rng.uniform(0.5, 1.8, 3)
        rot = (0.0, rng.uniform(0, 360), 0.0) if name == "cone" else tuple(rng.uniform(0, 360, 3))
        y = 0.0 if name == "cone" else 0.25 * s.max()
        shapes.append(mesh(meshes[name], ("sand", "moss", "clay")[k % 3], posed((x, y, z), rot, tuple(s))))
    return warprt.Scene(
        camera=camera((0.0, 2.6, 4.2), (0.0, 0.0, -1.2), 55.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.5), "sand": lambert((0.75, 0.65, 0.45)), "moss": lambert((0.3, 0.55, 0.25)),
                   "clay": lambert((0.7, 0.35, 0.25))},
        lights=(ceiling_light((-1.0, 5.0, -1.5), 3.0, 2.0, 3.0),
                warprt.SphereLight(center=(3.0, 2.5, 0.5), radius=0.3, radiance=25.0)))


# --- sphere and disk lights -------------------------------------------------------------------------------


def sphere_and_disk(width=None, height=None):
    """A sphere light and a tilted disk light, both just out of view, over spheres, a box and a
    torus."""
    size = _size(width, height, (256, 256))
    return warprt.Scene(
        camera=camera((0.0, 1.5, 4.0), (0.0, 0.6, 0.0), 45.0, size),
        shapes=(ground(), warprt.Sphere(center=(-0.8, 0.45, 0.2), radius=0.45, material="red"),
                warprt.Sphere(center=(0.9, 0.3, 0.6), radius=0.3, material="white"),
                warprt.Box(center=(0.3, 0.35, -0.6), size=(0.7, 0.7, 0.7), material="blue",
                           transform=yaw(30)),
                mesh(torus(48, 24, 0.35, 0.1), "white", posed((-0.2, 0.1, 1.0), (0, 0, 0)))),
        materials={"ground": lambert(0.6), "red": lambert((0.75, 0.2, 0.15)), "white": lambert(0.8),
                   "blue": lambert((0.2, 0.3, 0.75))},
        lights=(warprt.SphereLight(center=(-1.2, 2.6, 0.6), radius=0.25, radiance=(40.0, 34.0, 26.0)),
                warprt.DiskLight(center=(2.6, 1.4, 0.4), normal=(-0.8, -0.5, -0.2), radius=0.6,
                                 radiance=(8.0, 10.0, 13.0))))


def three_sphere_lights(width=None, height=None):
    """Three coloured sphere lights of radii 0.08, 0.2 and 0.5 and a disk light facing down, all
    above the view, over a torus, a cylinder and spheres."""
    size = _size(width, height, (320, 240))
    return warprt.Scene(
        camera=camera((0.5, 1.8, 4.5), (0.0, 0.5, 0.0), 45.0, size),
        shapes=(ground(), mesh(torus(96, 32, 0.55, 0.18), "white", posed((0.0, 0.18, 0.0))),
                warprt.Cylinder(start=(1.4, 0.0, -0.5), end=(1.4, 1.1, -0.5), radius=0.25, material="white"),
                warprt.Sphere(center=(-1.3, 0.35, 0.6), radius=0.35, material="white"),
                warprt.Sphere(center=(0.0, 0.3, 0.0), radius=0.3, material="white")),
        materials={"ground": lambert(0.55), "white": lambert(0.8)},
        lights=(warprt.SphereLight(center=(-1.0, 2.4, 1.2), radius=0.08, radiance=(300.0, 80.0, 40.0)),
                warprt.SphereLight(center=(0.6, 2.5, 1.8), radius=0.2, radiance=(10.0, 40.0, 12.0)),
                warprt.SphereLight(center=(1.8, 3.2, 0.5), radius=0.5, radiance=(4.0, 6.0, 14.0)),
                warprt.DiskLight(center=(0.0, 3.5, 0.5), normal=(0.0, -1.0, 0.0), radius=0.8, radiance=2.0)))


# --- many lights -------------------------------------------------------------------------------------------


def points_16(width=None, height=None):
    """16 coloured point lights on two rings over a cluster of spheres, a torus and a box."""
    size = _size(width, height, (256, 256))
    rng = np.random.default_rng(16)
    lights = []
    for k in range(16):
        a = 2 * np.pi * k / 8 + (0.4 if k >= 8 else 0.0)
        r, y = (2.2, 2.0) if k < 8 else (1.2, 3.0)
        lights.append(point_light((r * math.cos(a), y, r * math.sin(a)), tuple(rng.uniform(0.3, 1.6, 3))))
    shapes = [ground(), mesh(torus(64, 24, 0.45, 0.12), "white", posed((0.0, 0.12, 0.0))),
              warprt.Box(center=(0.0, 0.3, 0.0), size=(0.4, 0.6, 0.4), material="white", transform=yaw(20))]
    for k in range(7):
        a = 2 * np.pi * k / 7
        shapes.append(warprt.Sphere(center=(1.1 * math.cos(a), 0.2, 1.1 * math.sin(a)), radius=0.2, material="white"))
    return warprt.Scene(
        camera=camera((0.0, 2.4, 3.3), (0.0, 0.2, 0.0), 45.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.6), "white": lambert(0.8)}, lights=tuple(lights))


def mixed_32(width=None, height=None):
    """A hall of 12 pillars (cylinders) with 24 point lights and 8 small rectangle lights facing
    down, boxes between the pillars; the camera looks down from above the lights (their backs
    are black)."""
    size = _size(width, height, (320, 240))
    rng = np.random.default_rng(32)
    shapes = [ground()]
    for k in range(12):
        x, z = (-1.5 if k % 2 == 0 else 1.5), -1.0 * (k // 2) + 1.0
        shapes.append(warprt.Cylinder(start=(x, 0.0, z), end=(x, 2.4, z), radius=0.15, material="stone"))
    for k in range(10):
        shapes.append(warprt.Box(center=(0, 0, 0), size=tuple(rng.uniform(0.2, 0.5, 3)), material=("red", "stone")[k % 2],
                                 transform=posed((rng.uniform(-1.1, 1.1), 0.2, rng.uniform(-4.5, 0.8)),
                                                 (0, rng.uniform(0, 90), 0))))
    lights = [point_light((rng.uniform(-1.0, 1.0), rng.uniform(0.8, 2.2), rng.uniform(-5.0, 1.0)),
                          tuple(rng.uniform(0.05, 0.35, 3))) for _ in range(24)]
    lights += [ceiling_light((0.0, 2.4, 1.0 - 0.85 * k), 0.5, 0.3, tuple(rng.uniform(1.5, 4.0, 3))) for k in range(8)]
    return warprt.Scene(
        camera=camera((0.3, 2.9, 3.0), (0.0, 0.4, -2.0), 55.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.5), "stone": lambert((0.7, 0.68, 0.62)), "red": lambert((0.7, 0.25, 0.2))},
        lights=tuple(lights))


def spheres_64(width=None, height=None):
    """64 small sphere lights on an 8 x 8 grid above the view, over a 20k-triangle terrain and
    some boxes."""
    size = _size(width, height, (256, 256))
    rng = np.random.default_rng(64)
    lights = []
    for i in range(8):
        for j in range(8):
            lights.append(warprt.SphereLight(center=(-3.5 + i, 3.0 + 0.2 * ((i + j) % 3), -3.5 + j), radius=0.06,
                                             radiance=tuple(rng.uniform(40.0, 120.0, 3))))
    shapes = [mesh(terrain(100, 9.0, 0.5, seed=4), "ground")]
    for k in range(8):
        shapes.append(warprt.Box(center=(0, 0, 0), size=(0.4, 0.8, 0.4), material="white",
                                 transform=posed((rng.uniform(-3, 3), 0.6, rng.uniform(-3, 3)), (0, rng.uniform(0, 90), 0))))
    return warprt.Scene(
        camera=camera((0.0, 2.3, 5.0), (0.0, 0.0, -0.5), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.6), "white": lambert(0.8)}, lights=tuple(lights))


# --- mirrors and glass (Whitted recursion) ---------------------------------------------------------------------


def mirror_spheres(width=None, height=None):
    """Three mirror spheres and a standing mirror panel among Lambert spheres, lit by a
    rectangle light and a point light."""
    size = _size(width, height, (256, 256))
    return warprt.Scene(
        camera=camera((0.0, 1.4, 4.2), (0.0, 0.5, 0.0), 45.0, size),
        shapes=(ground(), warprt.Sphere(center=(-0.9, 0.5, 0.0), radius=0.5, material="mirror"),
                warprt.Sphere(center=(0.7, 0.35, 0.5), radius=0.35, material="mirror"),
                warprt.Sphere(center=(0.2, 0.25, -0.9), radius=0.25, material="mirror"),
                warprt.Sphere(center=(0.0, 0.3, 0.3), radius=0.3, material="red"),
                warprt.Sphere(center=(1.5, 0.4, -0.6), radius=0.4, material="blue"),
                warprt.Sphere(center=(-0.6, 0.2, 1.2), radius=0.2, material="yellow"),
                warprt.Sphere(center=(-1.8, 0.3, -0.9), radius=0.3, material="white"),
                # a mirror panel standing behind, facing the camera (edge1 x edge2 = +z)
                warprt.Rectangle(corner=(-1.2, 0.0, -2.0), edge1=(2.4, 0.0, 0.0), edge2=(0.0, 1.6, 0.0),
                                 material="mirror")),
        materials={"ground": lambert(0.55), "mirror": MIRROR, "red": lambert((0.8, 0.2, 0.15)),
                   "blue": lambert((0.2, 0.3, 0.8)), "yellow": lambert((0.85, 0.75, 0.2)), "white": lambert(0.8)},
        lights=(ceiling_light((0.5, 3.0, 1.0), 2.4, 2.0, 1.5), point_light((-2.0, 2.5, 2.0), 6.0)))


def mirror_room(width=None, height=None):
    """A closed room with a wide mirror low on its back wall, a sphere, a box and a cylinder under
    a ceiling panel out of view: the mirror shows the room behind the camera."""
    size = _size(width, height, (256, 256))
    shapes = room(-1.5, 1.5, 2.5, -1.5, 2.0, walls=("floor", "red", "green", "white", "white", "white")) + (
        warprt.Rectangle(corner=(-1.3, 0.15, -1.49), edge1=(2.6, 0.0, 0.0), edge2=(0.0, 1.25, 0.0), material="mirror"),
        warprt.Sphere(center=(0.6, 0.4, -0.5), radius=0.4, material="white"),
        warprt.Box(center=(0, 0, 0), size=(0.6, 0.9, 0.6), material="white", transform=posed((-0.7, 0.45, -0.2), (0, 25, 0))),
        warprt.Cylinder(start=(0.2, 0.0, 0.7), end=(0.2, 0.5, 0.7), radius=0.2, material="blue"))
    return warprt.Scene(
        camera=camera((0.6, 1.4, 1.9), (-0.2, 0.8, -1.5), 58.0, size), shapes=shapes,
        materials={"floor": lambert(0.5), "red": lambert((0.65, 0.1, 0.08)), "green": lambert((0.12, 0.5, 0.12)),
                   "white": lambert(0.75), "blue": lambert((0.2, 0.3, 0.7)), "mirror": MIRROR},
        lights=(ceiling_light((0.0, 2.485, 1.2), 0.8, 0.6, 10.0),))


def glass_ball(width=None, height=None):
    """A clear glass ball (ior 1.5, exact Fresnel) in front of coloured spheres and a tiled floor,
    under a rectangle light and a point light."""
    size = _size(width, height, (256, 256))
    shapes = [ground("dark")]
    for i in range(6):  # a band of lighter tiles behind the ball
        for j in range(4):
            if (i + j) % 2 == 0:
                shapes.append(warprt.Rectangle(corner=(-1.5 + 0.5 * i, 0.001, -1.6 + 0.5 * j), edge1=(0.0, 0.0, 0.5),
                                               edge2=(0.5, 0.0, 0.0), material="light"))
    shapes += [warprt.Sphere(center=(0.0, 0.55, 0.6), radius=0.55, material="glass"),
               warprt.Sphere(center=(-0.8, 0.35, -0.8), radius=0.35, material="red"),
               warprt.Sphere(center=(0.7, 0.35, -0.9), radius=0.35, material="blue"),
               warprt.Box(center=(0, 0, 0), size=(0.4, 0.8, 0.4), material="light", transform=posed((0.1, 0.4, -1.5), (0, 30, 0)))]
    return warprt.Scene(
        camera=camera((0.0, 1.2, 3.6), (0.0, 0.45, 0.0), 42.0, size), shapes=tuple(shapes),
        materials={"dark": lambert(0.3), "light": lambert(0.8), "glass": GLASS, "red": lambert((0.8, 0.2, 0.15)),
                   "blue": lambert((0.2, 0.3, 0.8))},
        lights=(ceiling_light((0.0, 3.0, 0.0), 1.5, 1.2, 5.0), point_light((2.5, 2.0, 2.5), 5.0)))


def glass_mesh(width=None, height=None):
    """A glass torus (8,192 triangles) and a glass box (ior 1.5, exact Fresnel) over coloured
    blocks, under a rectangle light."""
    size = _size(width, height, (256, 256))
    return warprt.Scene(
        camera=camera((0.3, 1.6, 3.2), (0.0, 0.4, 0.0), 45.0, size),
        shapes=(ground(), mesh(torus(128, 32, 0.5, 0.18), "glass", posed((-0.3, 0.5, 0.3), (60, 20, 0))),
                # (lifted off the ground: a glass face coplanar with the ground is ill-defined in any
                # renderer, which of the two a ray meets first is float round-off)
                warprt.Box(center=(0, 0, 0), size=(0.5, 0.5, 0.5), material="glass", transform=posed((0.8, 0.27, 0.5), (0, 35, 0))),
                warprt.Box(center=(0, 0, 0), size=(0.4, 1.0, 0.4), material="red", transform=posed((-0.5, 0.5, -0.8), (0, 10, 0))),
                warprt.Box(center=(0, 0, 0), size=(0.4, 0.6, 0.4), material="green", transform=posed((0.6, 0.3, -0.7), (0, -20, 0))),
                warprt.Sphere(center=(0.1, 0.25, -0.3), radius=0.25, material="yellow")),
        materials={"ground": lambert(0.6), "glass": GLASS, "red": lambert((0.8, 0.2, 0.15)),
                   "green": lambert((0.2, 0.7, 0.25)), "yellow": lambert((0.85, 0.75, 0.2))},
        lights=(ceiling_light((0.0, 3.0, 0.5), 1.4, 1.2, 5.0),))


# --- meshes from 1k to 2M triangles ----------------------------------------------------------------------------


def mesh_1k(width=None, height=None):
    """Low-poly meshes: a 1,280-triangle rock and a 1,024-triangle torus on the ground."""
    size = _size(width, height, (256, 256))
    return warprt.Scene(
        camera=camera((0.0, 1.6, 3.0), (0.0, 0.4, 0.0), 45.0, size),
        shapes=(ground(), mesh(displaced_sphere(3, 0.5, 0.3, seed=1), "rock", posed((-0.5, 0.5, 0.0))),
                mesh(torus(32, 16, 0.4, 0.14), "clay", posed((0.7, 0.4, 0.3), (70, 0, 20)))),
        materials={"ground": lambert(0.6), "rock": lambert((0.6, 0.55, 0.5)), "clay": lambert((0.75, 0.4, 0.3))},
        lights=(ceiling_light((0.5, 3.0, 1.0), 1.5, 1.0, 4.0),))


def mesh_80k(width=None, height=None):
    """An 81,920-triangle displaced sphere (a blob) under a rectangle light and a point light."""
    size = _size(width, height, (256, 256))
    return warprt.Scene(
        camera=camera((0.4, 1.5, 3.2), (0.0, 0.65, 0.0), 40.0, size),
        shapes=(ground(), mesh(displaced_sphere(6, 0.65, 0.18, seed=8, waves=24), "blob", posed((0.0, 0.78, 0.0)))),
        materials={"ground": lambert(0.6), "blob": lambert((0.5, 0.65, 0.8))},
        lights=(ceiling_light((-0.8, 3.0, 0.5), 1.2, 1.2, 5.0), point_light((2.0, 1.5, 2.0), 3.0)))


def mesh_500k(width=None, height=None):
    """A 524,288-triangle terrain (512 x 512 quads) under a large rectangle light low on one side
    and a point light."""
    size = _size(width, height, (320, 240))
    return warprt.Scene(
        camera=camera((0.0, 3.2, 5.0), (0.0, 0.3, -0.5), 55.0, size),
        shapes=(mesh(terrain(512, 10.0, 1.2, seed=7), "ground"),),
        materials={"ground": lambert((0.55, 0.5, 0.42))},
        lights=(facing_light((-6.5, 4.0, 0.0), (1.0, -0.6, 0.0), 4.0, 4.0, 2.5), point_light((2.0, 3.0, 1.0), 8.0)))


def mesh_2m(width=None, height=None):
    """A 2,097,152-triangle bumpy torus (1448 x 724 quads) on the ground under a rectangle light."""
    size = _size(width, height, (256, 256))
    v, f = torus(1448, 724, major=0.9, minor=0.35, bumps=0.06)
    return warprt.Scene(
        camera=camera((0.2, 2.0, 2.8), (0.0, 0.3, 0.0), 45.0, size),
        shapes=(ground(), mesh((v, f), "torus", posed((0.0, 0.35 * 1.06 + 0.01, 0.0), (0, 15, 0)))),
        materials={"ground": lambert(0.6), "torus": lambert((0.7, 0.6, 0.45))},
        lights=(ceiling_light((0.6, 3.0, 0.6), 1.6, 1.6, 3.5),))


# --- thin lens -------------------------------------------------------------------------------------------


def _focus_on(eye, look_at, point) -> float:
    """The distance along the view axis to the plane through ``point`` (the focus plane)."""
    eye, look_at, point = (np.asarray(x, float) for x in (eye, look_at, point))
    fwd = (look_at - eye) / np.linalg.norm(look_at - eye)
    return float(np.dot(point - eye, fwd))


def lens_row(width=None, height=None):
    """Nine spheres in a receding row, the lens (radius 0.12) focused on the fourth; a rectangle
    light and a point light."""
    size = _size(width, height, (320, 240))
    eye, look = (1.6, 0.8, 3.0), (-0.5, 0.3, -2.0)
    centres = [(-0.3 * k + 0.6, 0.3, 1.5 - 0.9 * k) for k in range(9)]
    shapes = [ground()] + [warprt.Sphere(center=c, radius=0.3, material=("red", "white", "blue")[k % 3])
                           for k, c in enumerate(centres)]
    return warprt.Scene(
        camera=camera(eye, look, 40.0, size, aperture=0.12, focus_distance=_focus_on(eye, look, centres[3])),
        shapes=tuple(shapes),
        materials={"ground": lambert(0.55), "red": lambert((0.8, 0.25, 0.2)), "white": lambert(0.8),
                   "blue": lambert((0.25, 0.35, 0.8))},
        lights=(ceiling_light((0.0, 3.0, -2.0), 2.0, 1.5, 4.0), point_light((3.0, 2.0, 2.0), 4.0)))


def lens_instances(width=None, height=None):
    """A field of 60 instanced rocks and tori through a lens of radius 0.2 focused at mid depth,
    lit by a disk light."""
    size = _size(width, height, (320, 240))
    rng = np.random.default_rng(21)
    rock, ring = displaced_sphere(4, 0.2, 0.2, seed=5), torus(48, 16, 0.18, 0.06)
    shapes = [ground()]
    for k in range(60):
        x, z = rng.uniform(-2.5, 2.5), rng.uniform(-6.0, 1.5)
        if k % 2:
            shapes.append(mesh(rock, "rock", posed((x, 0.2, z), tuple(rng.uniform(0, 360, 3)))))
        else:
            shapes.append(mesh(ring, "ring", posed((x, 0.18, z), (90, rng.uniform(0, 360), 0))))
    eye, look = (0.0, 1.0, 3.0), (0.0, 0.2, -2.0)
    return warprt.Scene(
        camera=camera(eye, look, 45.0, size, aperture=0.2, focus_distance=_focus_on(eye, look, (0.0, 0.2, -1.5))),
        shapes=tuple(shapes),
        materials={"ground": lambert(0.55), "rock": lambert((0.6, 0.55, 0.5)), "ring": lambert((0.8, 0.6, 0.3))},
        lights=(warprt.DiskLight(center=(1.0, 3.5, -1.0), normal=(-0.2, -1.0, 0.1), radius=1.2, radiance=4.0),))


# --- motion blur ----------------------------------------------------------------------------------------------


def moving_spheres(width=None, height=None):
    """Five spheres moving at different speeds and directions (one falls, one crosses the view),
    two still, under a rectangle light."""
    size = _size(width, height, (256, 256))
    shapes = (ground(),
              warprt.Sphere(center=(-1.2, 0.3, 0.0), center_end=(-0.4, 0.3, 0.0), radius=0.3, material="red"),
              warprt.Sphere(center=(0.4, 1.2, 0.3), center_end=(0.4, 0.35, 0.3), radius=0.35, material="white"),
              warprt.Sphere(center=(1.2, 0.25, -0.8), center_end=(1.2, 0.25, 0.2), radius=0.25, material="blue"),
              warprt.Sphere(center=(-0.3, 0.2, 1.0), center_end=(-0.1, 0.2, 1.05), radius=0.2, material="yellow"),
              warprt.Sphere(center=(-1.5, 0.6, -1.0), center_end=(0.8, 0.9, -1.4), radius=0.2, material="white"),
              warprt.Sphere(center=(-0.2, 0.4, -0.8), radius=0.4, material="white"),
              warprt.Sphere(center=(1.0, 0.15, 1.0), radius=0.15, material="red"))
    return warprt.Scene(
        camera=camera((0.0, 1.5, 4.0), (0.0, 0.4, 0.0), 42.0, size), shapes=shapes,
        materials={"ground": lambert(0.6), "red": lambert((0.8, 0.2, 0.15)), "white": lambert(0.8),
                   "blue": lambert((0.2, 0.3, 0.8)), "yellow": lambert((0.85, 0.75, 0.2))},
        lights=(ceiling_light((0.0, 3.0, 0.5), 1.5, 1.2, 5.0),))


def moving_mesh_camera(width=None, height=None):
    """The camera pans sideways while a torus (3,072 triangles) rises and turns 60 degrees and a
    box slides; still spheres; a rectangle light."""
    size = _size(width, height, (256, 256))
    ring = torus(48, 32, 0.45, 0.15)
    shapes = (ground(), mesh(ring, "gold", posed((0.0, 0.5, 0.0), (60, 0, 0)), posed((0.0, 0.8, 0.0), (60, 60, 0))),
              warprt.Box(center=(0, 0, 0), size=(0.5, 0.5, 0.5), material="blue",
                         transform=posed((0.9, 0.25, -0.5), (0, 10, 0)), transform_end=posed((1.3, 0.25, -0.3), (0, 40, 0))),
              warprt.Sphere(center=(-1.0, 0.35, -0.3), radius=0.35, material="white"),
              warprt.Sphere(center=(0.5, 0.2, 0.9), radius=0.2, material="white"))
    return warprt.Scene(
        camera=camera((-0.3, 1.6, 4.0), (0.0, 0.5, 0.0), 42.0, size, eye_end=(0.3, 1.6, 4.0), look_at_end=(0.15, 0.5, 0.0)),
        shapes=shapes,
        materials={"ground": lambert(0.6), "gold": lambert((0.8, 0.6, 0.25)), "blue": lambert((0.2, 0.3, 0.8)),
                   "white": lambert(0.8)},
        lights=(ceiling_light((0.5, 3.0, 0.8), 1.5, 1.2, 5.0),))


# --- high resolution ------------------------------------------------------------------------------------------


def spheres_720p(width=None, height=None):
    """1280 x 720: 400 spheres on a field under three point lights and two rectangle lights."""
    size = _size(width, height, (1280, 720))
    rng = np.random.default_rng(400)
    shapes = [ground()]
    for k in range(400):
        r = rng.uniform(0.08, 0.25)
        shapes.append(warprt.Sphere(center=(rng.uniform(-6, 6), r, rng.uniform(-8, 2)), radius=r,
                                    material=("red", "white", "blue", "yellow")[k % 4]))
    return warprt.Scene(
        camera=camera((0.0, 2.0, 5.0), (0.0, 0.0, -2.5), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.55), "red": lambert((0.8, 0.25, 0.2)), "white": lambert(0.8),
                   "blue": lambert((0.25, 0.35, 0.8)), "yellow": lambert((0.85, 0.75, 0.2))},
        lights=(point_light((-3.0, 3.0, 0.0), 15.0), point_light((3.0, 2.5, -4.0), (10.0, 12.0, 16.0)),
                point_light((0.0, 1.5, 2.0), (5.0, 4.0, 3.0)),
                ceiling_light((-2.0, 4.0, -4.0), 2.0, 2.0, 3.0), ceiling_light((3.0, 4.0, 0.0), 1.5, 1.5, 3.0)))


def street_1080p(width=None, height=None):
    """1920 x 1080: a street of 40 blocks (boxes), 16 lamp posts (cylinders) and 30 spheres under
    the sun (a directional light), 4 point lights and a rectangle light."""
    size = _size(width, height, (1920, 1080))
    rng = np.random.default_rng(1080)
    shapes = [ground()]
    for k in range(40):
        side = -1 if k % 2 else 1
        h = rng.uniform(0.8, 3.0)
        shapes.append(warprt.Box(center=(0, 0, 0), size=(rng.uniform(0.8, 1.4), h, rng.uniform(0.8, 1.5)),
                                 material=("wall", "brick")[k % 2 if k % 4 else 0],
                                 transform=posed((side * rng.uniform(2.2, 3.2), h / 2, 2.0 - 1.6 * (k // 2)))))
    for k in range(16):
        x = -1.5 if k % 2 else 1.5
        shapes.append(warprt.Cylinder(start=(x, 0.0, 1.0 - 2.0 * (k // 2)), end=(x, 1.6, 1.0 - 2.0 * (k // 2)),
                                      radius=0.05, material="metal"))
    for k in range(30):
        r = rng.uniform(0.1, 0.3)
        shapes.append(warprt.Sphere(center=(rng.uniform(-1.2, 1.2), r, rng.uniform(-25, 2)), radius=r, material="brick"))
    return warprt.Scene(
        camera=camera((0.2, 1.6, 5.0), (0.0, 0.8, -6.0), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.4), "wall": lambert((0.75, 0.72, 0.65)), "brick": lambert((0.65, 0.3, 0.2)),
                   "metal": lambert(0.5)},
        lights=(sun((0.4, -1.0, -0.6), (2.0, 1.9, 1.7)), point_light((-0.8, 1.5, 0.0), 3.0),
                point_light((0.8, 1.5, -4.0), 3.0), point_light((-0.8, 1.5, -8.0), 3.0),
                point_light((0.8, 1.5, -12.0), 3.0), ceiling_light((0.0, 4.0, 3.5), 2.0, 2.0, 2.0)))


# --- small robot-camera images -----------------------------------------------------------------------------


def _table_objects(rng, n, x_half, z_half, top):
    """n small objects on a table top at height ``top``: boxes, capsules lying down, cylinders
    standing."""
    out = []
    for k in range(n):
        x, z, a = rng.uniform(-x_half, x_half), rng.uniform(-z_half, z_half), rng.uniform(0, 180)
        m = ("red", "green", "blue", "yellow")[k % 4]
        kind = k % 3
        if kind == 0:
            s = rng.uniform(0.04, 0.09, 3)
            out.append(warprt.Box(center=(0, 0, 0), size=tuple(s), material=m, transform=posed((x, top + s[1] / 2, z), (0, a, 0))))
        elif kind == 1:
            r, hl = rng.uniform(0.015, 0.03), rng.uniform(0.03, 0.06)
            d = np.array([math.cos(math.radians(a)), 0.0, math.sin(math.radians(a))]) * hl
            c = np.array([x, top + r, z])
            out.append(warprt.Capsule(start=tuple(c - d), end=tuple(c + d), radius=r, material=m))
        else:
            r, h = rng.uniform(0.02, 0.04), rng.uniform(0.05, 0.12)
            out.append(warprt.Cylinder(start=(x, top, z), end=(x, top + h, z), radius=r, material=m))
    return out


_ROBOT_MATERIALS = {"ground": lambert(0.45), "table": lambert((0.6, 0.5, 0.38)), "red": lambert((0.8, 0.2, 0.15)),
                    "green": lambert((0.2, 0.7, 0.25)), "blue": lambert((0.2, 0.3, 0.8)),
                    "yellow": lambert((0.85, 0.75, 0.2)), "grey": lambert(0.6)}


def tabletop_64(width=None, height=None):
    """64 x 64 wrist camera: a table with 9 boxes, capsules and cylinders and a 2k-triangle mug
    (a torus handle beside a cylinder), under a ceiling panel and the sun."""
    size = _size(width, height, (64, 64))
    rng = np.random.default_rng(64)
    top = 0.75
    shapes = [ground(), warprt.Box(center=(0.0, top - 0.02, 0.0), size=(1.2, 0.04, 0.8), material="table")]
    shapes += _table_objects(rng, 9, 0.45, 0.3, top)
    shapes += [warprt.Cylinder(start=(0.1, top, 0.1), end=(0.1, top + 0.1, 0.1), radius=0.04, material="grey"),
               mesh(torus(64, 16, 0.03, 0.008), "grey", posed((0.145, top + 0.05, 0.1), (90, 0, 0)))]
    return warprt.Scene(
        camera=camera((0.0, top + 0.6, 0.55), (0.0, top, 0.0), 60.0, size), shapes=tuple(shapes),
        materials=_ROBOT_MATERIALS,
        lights=(ceiling_light((0.0, 2.5, 0.0), 1.0, 1.0, 6.0), sun((0.3, -1.0, 0.2), 1.5)))


def bin_128(width=None, height=None):
    """128 x 128 bin picking: a tray (5 boxes) holding 30 small boxes, capsules and cylinders and
    a 1,280-triangle part, an overhead panel and a point light."""
    size = _size(width, height, (128, 128))
    rng = np.random.default_rng(128)
    shapes = [ground(), warprt.Box(center=(0.0, 0.01, 0.0), size=(0.6, 0.02, 0.4), material="grey")]
    for c, s in (((0.0, 0.08, -0.2), (0.6, 0.16, 0.02)), ((0.0, 0.08, 0.2), (0.6, 0.16, 0.02)),
                 ((-0.3, 0.08, 0.0), (0.02, 0.16, 0.42)), ((0.3, 0.08, 0.0), (0.02, 0.16, 0.42))):
        shapes.append(warprt.Box(center=c, size=s, material="grey"))
    shapes += _table_objects(rng, 30, 0.25, 0.16, 0.02)
    shapes.append(mesh(displaced_sphere(3, 0.05, 0.25, seed=9), "yellow", posed((0.05, 0.07, 0.02))))
    return warprt.Scene(
        camera=camera((0.05, 0.7, 0.3), (0.0, 0.0, 0.0), 45.0, size), shapes=tuple(shapes),
        materials=_ROBOT_MATERIALS,
        lights=(ceiling_light((0.0, 1.5, 0.0), 0.8, 0.8, 6.0), point_light((0.6, 0.8, 0.6), 0.6)))


# --- contact shadows on a huge ground -----------------------------------------------------------------------


def contact_blocks(width=None, height=None):
    """Boxes and spheres resting on an infinite ground (the camera low, the horizon in view), a
    small rectangle light high up and a point light."""
    size = _size(width, height, (320, 240))
    rng = np.random.default_rng(77)
    shapes = [ground()]
    for k in range(8):
        s = rng.uniform(0.2, 0.6, 3)
        shapes.append(warprt.Box(center=(0, 0, 0), size=tuple(s), material=("white", "red")[k % 2],
                                 transform=posed((rng.uniform(-2.5, 2.5), s[1] / 2, rng.uniform(-4, 1)), (0, rng.uniform(0, 90), 0))))
    for k in range(8):
        r = rng.uniform(0.1, 0.35)
        shapes.append(warprt.Sphere(center=(rng.uniform(-2.5, 2.5), r, rng.uniform(-4, 1)), radius=r, material="white"))
    return warprt.Scene(
        camera=camera((0.0, 0.8, 3.5), (0.0, 0.3, -1.0), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.6), "white": lambert(0.8), "red": lambert((0.75, 0.25, 0.2))},
        lights=(ceiling_light((1.0, 6.0, 1.0), 0.6, 0.6, 60.0), point_light((-3.0, 4.0, 2.0), 10.0)))


def contact_figures(width=None, height=None):
    """Standing and lying capsules, cylinders and a 5k-triangle rock on an infinite ground under
    a low sun and a small sphere light."""
    size = _size(width, height, (320, 240))
    shapes = (ground(),
              warprt.Capsule(start=(-1.0, 0.2, 0.0), end=(-1.0, 1.2, 0.0), radius=0.2, material="white"),
              warprt.Capsule(start=(0.0, 0.15, 0.5), end=(0.8, 0.15, 0.2), radius=0.15, material="red"),
              warprt.Cylinder(start=(1.2, 0.0, -0.6), end=(1.2, 0.7, -0.6), radius=0.25, material="white"),
              warprt.Cylinder(start=(-0.2, 0.2, -1.0), end=(0.6, 0.2, -1.4), radius=0.2, material="blue"),
              mesh(displaced_sphere(4, 0.35, 0.2, seed=3), "white", posed((-0.3, 0.28, -0.3))))
    return warprt.Scene(
        camera=camera((0.5, 1.0, 3.5), (0.0, 0.35, -0.3), 45.0, size), shapes=shapes,
        materials={"ground": lambert(0.6), "white": lambert(0.8), "red": lambert((0.75, 0.25, 0.2)),
                   "blue": lambert((0.2, 0.3, 0.75))},
        lights=(sun((-0.7, -0.45, -0.4), 2.2), warprt.SphereLight(center=(1.5, 1.8, 1.5), radius=0.1, radiance=150.0)))


# --- edges and antialiasing --------------------------------------------------------------------------------


def fence(width=None, height=None):
    """A picket fence of 40 thin boards receding at an angle in front of a lit wall, one point
    light: only the pixel integral is noisy."""
    size = _size(width, height, (256, 256))
    a = math.radians(25.0)
    along = np.array([math.cos(a), 0.0, -math.sin(a)])
    shapes = [ground(), warprt.Rectangle(corner=(-6.0, 0.0, -3.0), edge1=(12.0, 0.0, 0.0), edge2=(0.0, 3.0, 0.0),
                                         material="wall")]
    for k in range(40):
        base = np.array([-2.0, 0.0, 0.5]) + 0.16 * k * along
        e1 = 0.05 * along  # e1 x e2 faces the camera side
        shapes.append(warprt.Rectangle(corner=tuple(base), edge1=tuple(e1), edge2=(0.0, 0.9, 0.0), material="board"))
    shapes.append(warprt.Rectangle(corner=(-2.0, 0.7, 0.5), edge1=tuple(6.4 * along), edge2=(0.0, 0.06, 0.0), material="board"))
    return warprt.Scene(
        camera=camera((0.0, 0.9, 3.5), (0.3, 0.5, 0.0), 45.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.4), "wall": lambert((0.85, 0.8, 0.7)), "board": lambert((0.4, 0.25, 0.15))},
        lights=(point_light((1.5, 3.0, 3.0), 20.0),))


def checker(width=None, height=None):
    """A 24 x 24 checkerboard of tiles receding towards the horizon (moiré), a few spheres, a
    point light and the sun."""
    size = _size(width, height, (320, 240))
    shapes = [ground("dark")]
    for i in range(24):
        for j in range(24):
            if (i + j) % 2 == 0:
                shapes.append(warprt.Rectangle(corner=(-6.0 + 0.5 * i, 0.0005, 1.0 - 0.5 * (j + 1)), edge1=(0.0, 0.0, 0.5),
                                               edge2=(0.5, 0.0, 0.0), material="light"))
    shapes += [warprt.Sphere(center=(-0.8, 0.3, -1.0), radius=0.3, material="red"),
               warprt.Sphere(center=(0.9, 0.2, -2.5), radius=0.2, material="red")]
    return warprt.Scene(
        camera=camera((0.0, 1.0, 2.5), (0.0, 0.2, -4.0), 50.0, size), shapes=tuple(shapes),
        materials={"dark": lambert(0.1), "light": lambert(0.85), "red": lambert((0.8, 0.2, 0.15))},
        lights=(point_light((1.0, 3.0, 1.0), 8.0), sun((-0.3, -1.0, -0.5), 1.0)))


# --- penumbrae ----------------------------------------------------------------------------------------------


def bars(width=None, height=None):
    """Six bars (boxes) at heights 0.1 to 1.2 over the ground under a large rectangle light out
    of view: penumbrae from sharp to wide."""
    size = _size(width, height, (256, 256))
    shapes = [ground()]
    for k in range(6):
        h = 0.1 + 0.22 * k
        shapes.append(warprt.Box(center=(-1.25 + 0.5 * k, h, -0.2), size=(0.12, 0.06, 2.0), material="white"))
        shapes.append(warprt.Cylinder(start=(-1.25 + 0.5 * k, 0.0, -1.1), end=(-1.25 + 0.5 * k, h, -1.1), radius=0.03,
                                      material="white"))
    return warprt.Scene(
        camera=camera((0.0, 2.2, 2.8), (0.0, 0.2, -0.3), 50.0, size), shapes=tuple(shapes),
        materials={"ground": lambert(0.65), "white": lambert(0.8)},
        lights=(ceiling_light((0.4, 2.8, 1.2), 2.0, 1.2, 3.5),))


def disk_penumbrae(width=None, height=None):
    """A 6k-triangle torus, a box and a capsule under a large disk light out of view."""
    size = _size(width, height, (320, 240))
    return warprt.Scene(
        camera=camera((0.5, 1.5, 3.5), (0.0, 0.3, 0.0), 42.0, size),
        shapes=(ground(), mesh(torus(96, 32, 0.45, 0.14), "blue", posed((-0.7, 0.55, 0.0), (70, 10, 0))),
                warprt.Box(center=(0, 0, 0), size=(0.4, 0.8, 0.4), material="white", transform=posed((0.6, 0.4, -0.4), (0, 30, 0))),
                warprt.Capsule(start=(0.2, 0.12, 0.8), end=(1.0, 0.5, 0.6), radius=0.12, material="red")),
        materials={"ground": lambert(0.65), "blue": lambert((0.3, 0.5, 0.85)), "white": lambert(0.8),
                   "red": lambert((0.8, 0.3, 0.25))},
        lights=(warprt.DiskLight(center=(-0.3, 2.6, 1.0), normal=(0.1, -1.0, -0.3), radius=0.9, radiance=3.0),))
