"""Motion blur against closed forms, in every path that renders it: a camera turning during the
shutter (the covered fraction of each pixel next to an edge) in single renders, in a batch's
worlds and in an animation frame; several spheres moving in a batch, whose blurred streaks need
the grouped BVH's bounds swept over the shutter.

Tolerances: each pixel value is the mean of spp indicator samples (covered or not) whose exact
mean c is the closed form, so over the pixels Σ(v - c) has variance at most V = Σ c(1 - c)/spp
(a stratifying sampler only lowers it) and Σ(v - c)² has mean at most V and variance at most
S4 = Σ c(1 - c)/spp · (1/spp² + 3 c(1 - c)/spp) (the fourth central moment of a binomial mean);
both are held within paths.Z_LIMIT of their bound (Chebyshev-style: the bounds are upper bounds).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import warprt
from warprt.animation import render_sequence
from warprt.worlds import BatchRenderer

import paths
from paths import FULL, Z_LIMIT

SPP = 64


def assert_coverage(img, c, spp, what):
    """Pixels ``img`` estimate the coverages ``c`` with ``spp`` indicator samples each."""
    v = np.asarray(img, np.float64)[..., 0].ravel()
    c = np.asarray(c, np.float64).ravel()
    var = c * (1 - c) / spp
    V = var.sum()
    S4 = (var * (1.0 / spp ** 2 + 3.0 * c * (1 - c) / spp)).sum()
    if V > 0:
        z_mean = (v - c).sum() / math.sqrt(V)
        z_square = (((v - c) ** 2).sum() - V) / math.sqrt(S4)
        assert abs(z_mean) < Z_LIMIT and z_square < Z_LIMIT, \
            f"{what}: z of the mean {z_mean:.2f}, of the squares {z_square:.2f}"
    # pixels the edge never reaches are exactly covered or exactly not
    np.testing.assert_array_equal(v[c == 0.0], 0.0, err_msg=what)
    np.testing.assert_array_equal(v[c == 1.0], 1.0, err_msg=what)


# --- a turning camera -------------------------------------------------------------------------

EW, EH, FOV, DIST = 48, 4, 4.0, 10.0


def _edge_scene(look_end=None) -> warprt.Scene:
    """A level pinhole camera at the origin looking down -z (turning to ``look_end``, a unit
    vector, over the shutter) and a flat surface covering x > 0 of the plane z = -DIST, shown
    by the ambient term alone (value 1 where it is seen, 0 elsewhere)."""
    wall = warprt.Rectangle(corner=(0.0, -50.0, -DIST), edge1=(100.0, 0.0, 0.0), edge2=(0.0, 100.0, 0.0),
                            material="flat")
    cam = warprt.Camera(eye=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0), fov=FOV, width=EW, height=EH,
                        look_at_end=None if look_end is None else tuple(look_end))
    return warprt.Scene(camera=cam, shapes=(wall,), materials={"flat": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0,
                        render=warprt.RenderSettings(sampler="stratified", spp=SPP, adaptive=False))


def heading(degrees: float) -> tuple:
    """The unit vector the camera looks along when it has turned ``degrees`` towards +x."""
    a = math.radians(degrees)
    return (math.sin(a), 0.0, -math.cos(a))


def edge_coverage(turn: float, k: int = 4000) -> np.ndarray:
    """Each pixel's exact covered fraction (per column: the edge is vertical) while the look-at
    point moves linearly from (0, 0, -1) to heading(turn) over the shutter.

    At time t the camera heads at ψ(t) = atan2(t sin θ, 1 - t + t cos θ) from -z towards +x; the
    ray through raster x leaves it at φ(x) = atan(us(x)) (image plane at distance 1) and meets the
    plane z = -DIST at x = DIST tan(ψ + φ): it sees the surface when ψ(t) > -φ(x). ψ is monotone in
    t, so the covered times are t > t* (θ > 0) or t < t* (θ < 0), t* = tan β / (sin θ + tan β (1 -
    cos θ)) with β = -φ; the film integral is a midpoint sum over k points a pixel."""
    th = math.radians(turn)
    right = math.tan(math.radians(FOV) / 2) * EW / EH
    x = (np.arange(EW * k) + 0.5) / k
    beta = -np.arctan(-right + 2 * right * x / EW)
    if th == 0:
        cov = (beta < 0).astype(float)
    else:
        tb = np.tan(beta)
        t_star = tb / (math.sin(th) + tb * (1 - math.cos(th)))
        # ψ runs from 0 to θ: outside that range β is always or never passed
        inside = (beta - 0.0) * (beta - th) < 0
        frac = np.clip(t_star, 0.0, 1.0)
        if th > 0:
            cov = np.where(inside, 1.0 - frac, (beta <= 0).astype(float))
        else:
            cov = np.where(inside, frac, (beta <= th).astype(float))
    col = cov.reshape(EW, k).mean(axis=1)
    return np.tile(col, (EH, 1))


TURN, TURN_OTHER = 20.0, -12.0


def test_turning_camera_blurs_an_edge_as_the_closed_form_says():
    """A single render: the edge smears over the columns the turn sweeps it across."""
    c = edge_coverage(TURN)
    assert ((c > 0.02) & (c < 0.98)).sum() >= 10 * EH  # a wide blur, not an edge
    img = warprt.Renderer(_edge_scene(heading(TURN)), device="cpu", features=FULL).render(
        spp=SPP, seed=1, progress=False).image
    assert_coverage(img, c, SPP, "single render")
    # a shutter held open at one instant shows the edge sharp where the turn starts
    sharp = warprt.Renderer(_edge_scene(heading(TURN)).with_camera(shutter=(0.0, 0.0)), device="cpu",
                            features=FULL).render(spp=SPP, seed=1, progress=False).image
    assert_coverage(sharp, edge_coverage(0.0), SPP, "shutter [0, 0]")


def test_turning_cameras_in_a_batch_blur_as_the_closed_form_says():
    """Camera poses at shutter open and close, two worlds turning opposite ways, two cameras."""
    scene = _edge_scene()
    br = BatchRenderer(scene, worlds=2, cameras=2, device="cpu", features=FULL, motion_blur=True)
    origin = np.zeros(3)
    start = np.tile(paths.camera_pose(origin, (0.0, 0.0, -1.0)), (2, 2, 1))
    end = start.copy()
    turns = {(0, 0): TURN, (0, 1): 0.0, (1, 0): TURN_OTHER, (1, 1): TURN / 2}
    for (w, c), t in turns.items():
        end[w, c] = paths.camera_pose(origin, heading(t))
    br.set_camera_poses(start, end=end)
    out = br.render(spp=SPP, seed=2).numpy()
    for (w, c), t in turns.items():
        assert_coverage(out[w, c], edge_coverage(t), SPP, f"batch world {w} camera {c} ({t} degrees)")


def test_a_keyframed_camera_pan_blurs_its_frame_as_the_closed_form_says():
    """Frame 0 of a pan keyed from -z (time 0) to heading(TURN) (time 1) at 1 frame a second:
    the shutter spans the whole pan; frame 1, after the last key, is sharp at the end."""
    scene = _edge_scene().replace(animation=warprt.Animation(frames=2, fps=1.0))
    cam = scene.camera
    scene = scene.with_camera(keyframes=({"time": 0.0, "look_at": cam.look_at}, {"time": 1.0, "look_at": heading(TURN)}))
    frames = render_sequence(scene, frames=[0, 1], spp=SPP, seed=3, progress=False)
    assert_coverage(frames[0], edge_coverage(TURN), SPP, "frame 0")
    right = math.tan(math.radians(FOV) / 2) * EW / EH
    x = (np.arange(EW) + 0.5)
    phi = np.degrees(np.arctan(-right + 2 * right * x / EW))
    sharp = frames[1][..., 0]
    # the edge at the end heading: columns whose centre looks left of -TURN are dark, right of it lit
    far = np.abs(phi + TURN) > np.degrees(2 * right / EW)  # (a column's width away from the edge)
    np.testing.assert_array_equal(sharp[:, far], np.tile((phi[far] > -TURN).astype(np.float32), (EH, 1)))


# --- several moving spheres in a batch: swept bounds -------------------------------------------

SW, SH = 48, 24


def _spheres_scene(centres, radius) -> warprt.Scene:
    cam = warprt.Camera(eye=(0.0, 0.0, 8.0), look_at=(0.0, 0.0, 0.0), fov=30.0, width=SW, height=SH)
    shapes = tuple(warprt.Sphere(center=tuple(c), radius=radius, material="flat") for c in centres)
    return warprt.Scene(camera=cam, shapes=shapes, materials={"flat": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0,
                        render=warprt.RenderSettings(sampler="stratified", spp=SPP, adaptive=False))


def sphere_coverage(cam: warprt.Camera, starts, ends, radius, k: int = 16) -> np.ndarray:
    """Each pixel's covered fraction by spheres moving linearly from ``starts`` to ``ends``
    (centres) over the shutter, in float64: a ray e + s d meets the sphere centred at c(t) while
    |P (c(t) - e)|² < r² (P: the projection off d), a quadratic in t, so each sphere covers an
    interval of the shutter; their union's length by inclusion and exclusion, averaged over k x k
    film points a pixel (midpoints)."""
    eye = np.asarray(cam.eye, np.float64)
    u, v, w = cam.basis(0.0)
    top = math.tan(math.radians(cam.fov) / 2)
    right = top * cam.width / cam.height
    g = (np.arange(k) + 0.5) / k
    fy, fx = np.meshgrid(np.repeat(np.arange(cam.height), k) + np.tile(g, cam.height),
                         np.repeat(np.arange(cam.width), k) + np.tile(g, cam.width), indexing="ij")
    us = (-right + 2 * right * fx / cam.width).ravel()
    vs = (top - 2 * top * fy / cam.height).ravel()
    d = us[:, None] * u + vs[:, None] * v - w
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    spans = []
    for c0, c1 in zip(starts, ends):
        a0 = np.asarray(c0, np.float64) - eye
        delta = np.asarray(c1, np.float64) - np.asarray(c0, np.float64)
        p0 = a0 - (d @ a0)[:, None] * d  # P (c(0) - e)
        pd = delta - (d @ delta)[:, None] * d  # P delta
        qa, qb, qc = (pd * pd).sum(1), 2 * (p0 * pd).sum(1), (p0 * p0).sum(1) - radius * radius
        disc = qb * qb - 4 * qa * qc
        root = np.sqrt(np.maximum(disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            lo = np.where(qa > 0, (-qb - root) / (2 * qa), np.where(qc < 0, 0.0, 2.0))
            hi = np.where(qa > 0, (-qb + root) / (2 * qa), np.where(qc < 0, 1.0, 2.0))
        lo, hi = np.where(disc > 0, lo, 2.0), np.where(disc > 0, hi, 2.0)
        spans.append((np.clip(lo, 0, 1), np.clip(hi, 0, 1)))
    total = np.zeros(len(d))
    for n in range(1, len(spans) + 1):  # inclusion and exclusion over the spheres' intervals
        for group in itertools.combinations(spans, n):
            lo = np.max([s[0] for s in group], axis=0)
            hi = np.min([s[1] for s in group], axis=0)
            total += (-1) ** (n + 1) * np.maximum(hi - lo, 0.0)
    return total.reshape(cam.height, k, cam.width, k).mean(axis=(1, 3))


def test_several_moving_spheres_in_a_batch_blur_as_the_closed_form_says():
    """Three spheres, each moving its own way in each world (poses at shutter open and close):
    the batch's grouped BVH (from two bounded shapes on) must hold each sphere's box swept over
    the shutter, or the leading part of its streak goes missing. The single render of world 0's
    spheres (centre and centre_end) takes the same closed form."""
    r = 0.35
    base = [(-1.2, 0.7, 0.0), (0.0, 0.0, 0.0), (1.0, -0.7, 0.0)]
    scene = _spheres_scene(base, r)
    br = BatchRenderer(scene, worlds=2, cameras=1, device="cpu", features=FULL, motion_blur=True)
    assert br.bvh is not None
    moves = [[(0.9, 0.0, 0.0), (-0.8, 0.2, 0.0), (0.0, 0.0, 1.5)],  # world 0: right, left and up, towards the eye
             [(0.0, 0.5, 0.0), (1.2, 0.0, -2.0), (-1.0, 0.0, 0.0)]]
    start = np.tile(paths.IDENTITY, (2, 3, 1))
    end = start.copy()
    end[..., :3] = np.asarray(moves)
    br.set_shape_poses(start, end=end)
    out = br.render(spp=SPP, seed=4).numpy()
    for w in range(2):
        ends = [tuple(np.add(b, m)) for b, m in zip(base, moves[w])]
        c = sphere_coverage(scene.camera, base, ends, r)
        assert ((c > 0.05) & (c < 0.95)).sum() > 60  # the streaks are there
        assert_coverage(out[w, 0], c, SPP, f"batch world {w}")
        if w == 0:
            moving = _spheres_scene(base, r).replace(shapes=tuple(
                warprt.Sphere(center=b, center_end=e, radius=r, material="flat") for b, e in zip(base, ends)))
            img = warprt.Renderer(moving, device="cpu", features=FULL).render(spp=SPP, seed=4, progress=False).image
            assert_coverage(img, c, SPP, "single render")
