"""AOVs averaged over the colour's own samples, against the same samples traced on the host.

The sampler's points for every pixel (``warprt.query.pixel_samples``: film, lens) give the
camera rays of each sample (``warprt.camera_rays``); the host intersects them with the scene in
float64 and averages exactly as warprt.aov documents: coverage = hits / samples, depth and z the
mean over hits, the id the most frequent (ties: seen first). Tolerances: coverage and ids exact
except where a sample ray passes within float32 rounding of a silhouette (counted, a handful
allowed); depths to float32 rounding of the ray directions, amplified on the floor seen at a
grazing angle 1e3 units away (measured worst 2.4e-6 relative, bound 1e-5).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import warp as wp

import warprt
from warprt.aov import AOV_NAMES
from warprt.query import pixel_samples

W, H, SPP = 16, 12, 8


def scene(aperture=0.0, sampler="sobol"):
    """A tilted floor, a rectangle whose left edge crosses the image (seen from its back: its
    normal edge1 × edge2 points away from the camera), and a sphere: pixels with one, two and
    three surfaces, and sky. Uniform sampling (every pixel the same count, as the host's
    expectations take it) unless a test asks for adaptive sampling."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1.5, 4), look_at=(0, 0.5, 0), fov=40, width=W, height=H, aperture=aperture,
                             focus_distance=4.0),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0.1, 1, 0), material="floor"),
                warprt.Rectangle(corner=(0.05, 0.0, -0.5), edge1=(0, 1.2, 0), edge2=(3, 0, 0), material="wall"),
                warprt.Sphere(center=(-0.6, 0.6, 0.3), radius=0.45, material="ball")),
        materials={"floor": warprt.Material(kd=0.5), "wall": warprt.Material(kd=(0.2, 0.6, 0.3)),
                   "ball": warprt.Material(kd=(0.8, 0.2, 0.1))},
        lights=(warprt.PointLight(position=(1, 4, 3)),),
        render=warprt.RenderSettings(sampler=sampler, spp=SPP, adaptive=False))


def host_hits(sc, o, d):
    """(t, shape index) of the nearest hit of each ray in float64 (-1 for none), and a margin:
    how close the ray passes to any silhouette (relative)."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = np.array([0.1, 1, 0]) / np.linalg.norm([0.1, 1, 0])
    t_plane = np.where(d @ n < 0, -(o @ n) / (d @ n), np.inf)
    rect = sc.shapes[1]
    c, e1, e2 = (np.asarray(x, np.float64) for x in (rect.corner, rect.edge1, rect.edge2))
    t_r = (c[2] - o[:, 2]) / d[:, 2]
    p = o + t_r[:, None] * d
    a, b = (p - c) @ e1 / (e1 @ e1), (p - c) @ e2 / (e2 @ e2)
    inside = (a > 0) & (a < 1) & (b > 0) & (b < 1) & (t_r > 0)
    margin_r = np.minimum.reduce([np.abs(a), np.abs(1 - a), np.abs(b), np.abs(1 - b)])
    t_rect = np.where(inside, t_r, np.inf)
    s = sc.shapes[2]
    f = o - np.asarray(s.center)
    bq = np.sum(f * d, axis=1)
    disc = s.radius ** 2 - (np.sum(f * f, axis=1) - bq * bq)
    t_s = np.where(disc >= 0, -bq - np.sqrt(np.maximum(disc, 0)), np.inf)
    t_s = np.where(t_s > 0, t_s, np.inf)
    ts = np.stack([t_plane, t_rect, t_s], axis=1)
    idx = np.argmin(ts, axis=1)
    t = ts[np.arange(len(ts)), idx]
    shape = np.where(np.isfinite(t), idx, -1)
    margin = np.minimum(margin_r, np.abs(disc) / s.radius ** 2)
    return t, shape, margin


def expected(sc, counts=None):
    """coverage, depth, object id and the doubtful pixels (a sample ray within float32 rounding
    of a silhouette) from each pixel's first ``counts`` samples (default SPP)."""
    counts = np.full(W * H, SPP) if counts is None else np.asarray(counts).reshape(-1)
    n = int(counts.max())
    pixels = np.arange(W * H)
    film = pixel_samples(sc.render.sampler, pixels, SPP, dim=0, count=n)  # (N, n, 2)
    lens = pixel_samples(sc.render.sampler, pixels, SPP, dim=1, count=n)
    px = np.stack([pixels % W, pixels // W], axis=1)[:, None, :] + film
    o, d = warprt.camera_rays(sc, points=px.reshape(-1, 2), lens=lens.reshape(-1, 2))
    t, shape, margin = host_hits(sc, o, d)
    t, shape, margin = (x.reshape(W * H, n) for x in (t, shape, margin))
    taken = np.arange(n)[None, :] < counts[:, None]
    shape = np.where(taken, shape, -1)
    margin = np.where(taken, margin, np.inf)
    hits = shape >= 0
    coverage = hits.sum(axis=1) / counts
    with np.errstate(invalid="ignore"):
        depth = np.where(hits.any(axis=1), np.where(hits, t, 0).sum(axis=1) / hits.sum(axis=1), np.inf)
    ids = np.full(W * H, -1)
    for i in range(W * H):
        seen = [s for s in shape[i] if s >= 0]
        if seen:
            order = list(dict.fromkeys(seen))
            counts_i = [seen.count(s) for s in order]
            ids[i] = order[int(np.argmax(counts_i))]  # argmax: the first of the largest
    doubtful = (margin < 1e-4).any(axis=1)
    return coverage.reshape(H, W), depth.reshape(H, W), ids.reshape(H, W), doubtful.reshape(H, W)


@pytest.mark.parametrize("aperture", [0.0, 0.15])
def test_aovs_average_the_colour_samples(aperture):
    sc = scene(aperture)
    out = warprt.Renderer(sc, device="cpu").render(spp=SPP, progress=False,
                                                     aovs=["coverage", "depth", "object_id", "material"])
    coverage, depth, ids, doubtful = expected(sc)
    ok = ~doubtful
    assert ok.sum() > 0.8 * W * H
    partial = ok & (coverage > 0) & (coverage < 1)
    assert partial.sum() >= 8  # silhouettes and the sky edge really are averaged over
    np.testing.assert_array_equal(out.aovs["coverage"][ok], coverage[ok].astype(np.float32))
    np.testing.assert_array_equal(out.aovs["object_id"][ok], ids[ok])
    mats = np.where(ids >= 0, ids, -1)  # material i is the i-th shape's here (+ the default one first)
    names = list(sc.materials)
    expect_mat = np.array([names.index(sc.shapes[i].material) if i >= 0 else -1 for i in mats.ravel()])
    np.testing.assert_array_equal(out.aovs["material"][ok], expect_mat.reshape(H, W)[ok])
    finite = ok & np.isfinite(depth)
    np.testing.assert_allclose(out.aovs["depth"][finite], depth[finite], rtol=1e-5)
    assert np.isposinf(out.aovs["depth"][ok & ~np.isfinite(depth)]).all()


def test_ids_are_the_majority_not_the_first_or_last_sample():
    """Somewhere a pixel's first (or last) sample sees another object than most of its samples:
    the id must be the most frequent one there."""
    sc = scene()
    pixels = np.arange(W * H)
    film = pixel_samples("sobol", pixels, SPP, dim=0)
    px = np.stack([pixels % W, pixels // W], axis=1)[:, None, :] + film
    o, d = warprt.camera_rays(sc, points=px.reshape(-1, 2))
    _, shape, margin = host_hits(sc, o, d)
    shape = shape.reshape(W * H, SPP)
    out = warprt.Renderer(sc, device="cpu").render(spp=SPP, progress=False, aovs=["object_id"]).aovs["object_id"]
    _, _, ids, doubtful = expected(sc)
    differs_first = (~doubtful.ravel()) & (shape[:, 0] != ids.ravel())
    differs_last = (~doubtful.ravel()) & (shape[:, -1] != ids.ravel())
    assert differs_first.any() and differs_last.any()
    np.testing.assert_array_equal(out.ravel()[differs_first | differs_last], ids.ravel()[differs_first | differs_last])


class StopAfter:
    """A ``stop`` event that is set once it has been read ``n`` times (after the n-th pass)."""

    def __init__(self, n):
        self.n = n

    def is_set(self):
        self.n -= 1
        return self.n < 0


@pytest.mark.parametrize("size", [(16, 12), (37, 23)])
def test_aovs_are_the_same_for_any_workers_slices_or_passes(size):
    """The render kernel adds each camera sample to its pixel's AOV sums in sample order, in the
    thread that owns the pixel (``warprt.aov``): every AOV is the same bit for bit with 1, 2 and
    3 workers, fixed slices, and passes of one or three samples (the sums wait between passes)."""
    w, h = size
    sc = scene()
    sc = sc.replace(camera=dataclasses.replace(sc.camera, width=w, height=h))
    names = list(AOV_NAMES)
    r = warprt.Renderer(sc, device="cpu")
    # (12 samples: a renderer's first pass is one sample, its second the other 11, whose first 8
    # of a pixel go as one camera packet; passes of 1 or 3 mix the pixels in every packet)
    one = r.render(spp=12, progress=False, aovs=names, workers=1)
    assert 0 < one.aovs["coverage"].mean() < 1
    for options in (dict(workers=2), dict(workers=3), dict(workers=2, slices=5), dict(workers=1, pass_spp=1),
                    dict(workers=2, pass_spp=3), dict(workers=2, slices=3, pass_spp=1)):
        out = r.render(spp=12, progress=False, aovs=names, **options)
        assert out.image.tobytes() == one.image.tobytes(), options
        for name in names:
            assert out.aovs[name].tobytes() == one.aovs[name].tobytes(), (name, options)


def test_a_stopped_render_has_the_aovs_of_the_samples_it_holds():
    """A render stopped after its second pass (``stop``, as Ctrl-C) holds two samples a pixel;
    its AOVs are those of a two-sample render, bit for bit (Sobol points do not depend on the
    planned count): there the last pass writes them, here ``aov_finish`` after the passes, by the
    same rules."""
    sc = scene(sampler="sobol")
    names = list(AOV_NAMES)
    r = warprt.Renderer(sc, device="cpu")
    stopped = r.render(spp=8, pass_spp=1, stop=StopAfter(1), progress=False, aovs=names)
    assert stopped.interrupted and stopped.spp == 2
    two = r.render(spp=2, pass_spp=1, progress=False, aovs=names)
    assert stopped.image.tobytes() == two.image.tobytes()  # the same samples
    for name in names:
        assert stopped.aovs[name].tobytes() == two.aovs[name].tobytes(), name
    coverage, depth, ids, doubtful = expected(sc, counts=np.full(W * H, 2))
    ok = ~doubtful
    np.testing.assert_array_equal(stopped.aovs["coverage"][ok], coverage[ok].astype(np.float32))
    np.testing.assert_array_equal(stopped.aovs["object_id"][ok], ids[ok])


def test_adaptive_aovs_use_each_pixels_own_count():
    """With adaptive sampling every pixel has its own count (``film.adaptive_counts``); its
    coverage, depth and id are those of its own samples, against the host's float64 traces."""
    sc = scene(sampler="sobol")
    r = warprt.Renderer(sc, device="cpu")
    out = r.render(spp=SPP, progress=False, adaptive=True, aovs=["coverage", "depth", "object_id"])
    counts = r._film.counts
    assert counts is not None and counts.min() < counts.max()
    coverage, depth, ids, doubtful = expected(sc, counts=counts)
    ok = ~doubtful
    assert ok.sum() > 0.8 * W * H
    np.testing.assert_array_equal(out.aovs["coverage"][ok], coverage[ok].astype(np.float32))
    np.testing.assert_array_equal(out.aovs["object_id"][ok], ids[ok])
    finite = ok & np.isfinite(depth)
    np.testing.assert_allclose(out.aovs["depth"][finite], depth[finite], rtol=1e-5)


def test_as_warp_returns_every_aov_on_the_device():
    sc = scene()
    names = ["depth", "normal", "coverage", "object_id", "motion"]
    host = warprt.Renderer(sc, device="cpu").render(spp=2, progress=False, aovs=names)
    dev = warprt.Renderer(sc, device="cpu").render(spp=2, progress=False, aovs=names, as_warp=True)
    assert isinstance(dev.image, wp.array)
    for name in names:
        a = dev.aovs[name]
        assert isinstance(a, wp.array) and str(a.device) == "cpu", name
        np.testing.assert_array_equal(a.numpy(), host.aovs[name])
        assert a.numpy().shape == host.aovs[name].shape


def test_aov_exr_round_trip_keeps_ids_and_the_miss_value(tmp_path):
    sc = scene()
    out = warprt.render(sc, spp=4, aovs=["depth", "coverage", "object_id", "material", "normal"])
    path = tmp_path / "aov.exr"
    warprt.save_image(out, path)
    rgb, _, layers = warprt.read_exr(path, layers=True)
    for name in ("depth", "coverage", "object_id", "material", "normal"):
        assert layers[name].dtype == out[name].dtype, name
        np.testing.assert_array_equal(layers[name], out[name])
    assert (out["object_id"] == -1).any() and np.isposinf(out["depth"][out["object_id"] == -1]).all()


def traced_aovs(sc, spp):
    """Every AOV but motion, from each pixel's spp camera samples (the sampler's film and lens
    points, ``camera_rays``) traced one by one by ``trace_rays`` and averaged on the host in float64
    by the rules of ``warprt.aov``; and the pixels where a sample ray passes within float32
    rounding of a silhouette (``host_hits``: their hits may differ)."""
    pixels = np.arange(W * H)
    film = pixel_samples(sc.render.sampler, pixels, spp, dim=0)
    lens = pixel_samples(sc.render.sampler, pixels, spp, dim=1)
    px = np.stack([pixels % W, pixels // W], axis=1)[:, None, :] + film
    o, d = warprt.camera_rays(sc, points=px.reshape(-1, 2), lens=lens.reshape(-1, 2))
    tr = warprt.trace_rays(sc, o, d)
    _, _, margin = host_hits(sc, o, d)
    d = d.astype(np.float64)
    hit = tr["hit"].reshape(W * H, spp)
    t = np.where(tr["hit"], tr["t"], 0.0).astype(np.float64)
    ns = tr["shading_normal"].astype(np.float64)
    ns = np.where((np.sum(ns * d, axis=1) > 0)[:, None], -ns, ns)  # turned towards the camera
    eye, look = np.array(sc.camera.eye, np.float64), np.array(sc.camera.look_at, np.float64)
    w = (eye - look) / np.linalg.norm(eye - look)
    names = list(sc.materials)
    kd = np.array([np.broadcast_to(np.asarray(sc.materials[sc.shapes[i].material].kd, np.float64), 3)
                   for i in range(len(sc.shapes))])
    mat = np.array([names.index(s.material) for s in sc.shapes])
    shape = tr["shape"]
    per_sample = {"depth": t, "z": t * -(d @ w), "normal": ns, "position": tr["position"].astype(np.float64),
                  "albedo": np.where(tr["hit"][:, None], kd[np.maximum(shape, 0)], 0.0)}
    n_hits = hit.sum(axis=1)
    out = {"coverage": n_hits / spp}
    with np.errstate(invalid="ignore", divide="ignore"):
        for name, v in per_sample.items():
            v = np.where(tr["hit"].reshape(-1, *([1] * (v.ndim - 1))), v, 0.0).reshape(W * H, spp, *v.shape[1:])
            mean = v.sum(axis=1) / np.maximum(n_hits, 1).reshape(-1, *([1] * (v.ndim - 2)))
            if name in ("depth", "z"):
                mean = np.where(n_hits > 0, mean, np.inf)
            if name == "normal":
                length = np.linalg.norm(mean, axis=1, keepdims=True)
                mean = np.where(length > 0, mean / np.where(length > 0, length, 1), 0.0)
            out[name] = mean
    ids = np.full(W * H, -1)
    shape = shape.reshape(W * H, spp)
    for i in range(W * H):
        seen = [s for s in shape[i] if s >= 0]
        if seen:
            order = list(dict.fromkeys(seen))
            ids[i] = order[int(np.argmax([seen.count(s) for s in order]))]
    out["object_id"] = ids
    out["material"] = np.where(ids >= 0, mat[np.maximum(ids, 0)], -1)
    doubtful = (margin.reshape(W * H, spp) < 1e-4).any(axis=1)
    return {k: v.reshape(H, W, *v.shape[1:]) for k, v in out.items()}, doubtful.reshape(H, W)


@pytest.mark.parametrize("aperture,sampler,spp", [(0.0, "regular", 1), (0.15, "sobol", 2 * SPP)])
def test_every_aov_is_the_mean_of_its_samples_traced_one_by_one(aperture, sampler, spp):
    """The render kernel's AOVs against its own camera samples traced one at a time on the side
    (``trace_rays``) and averaged on the host: at one regular sample a pixel (the pixel centre:
    every AOV is the one hit's) and at 16 Sobol samples through a lens (means over hits, the
    renormalised normal, the majority id; a fresh renderer's second pass takes 8 of a pixel's
    samples as one camera packet, the rest with the next pixel's). Coverage and ids exactly (away from silhouettes);
    the means to float32 rounding of the kernel's sums and of the side traces' directions
    (measured worst over the regular, stratified, Sobol and independent samplers at 1 to 16
    samples: depth and z 6.4e-7 relative, normal 5.1e-7, position 6.9e-7 of |p|, albedo
    1.3e-7), bounded at 3x that."""
    sc = scene(aperture, sampler)
    names = [n for n in AOV_NAMES if n != "motion"]
    out = warprt.Renderer(sc, device="cpu").render(spp=spp, progress=False, aovs=names + ["motion"]).aovs
    ref, doubtful = traced_aovs(sc, spp)
    ok = ~doubtful
    assert ok.sum() > 0.8 * W * H and (ref["coverage"][ok] == 1).sum() > 0.3 * W * H
    if spp > 1:
        assert ((ref["coverage"][ok] > 0) & (ref["coverage"][ok] < 1)).sum() >= 8
    for name in ("coverage", "object_id", "material"):
        np.testing.assert_array_equal(out[name][ok], ref[name][ok].astype(out[name].dtype), err_msg=name)
    hit = ok & (ref["coverage"] > 0)
    assert np.isposinf(out["depth"][ok & ~hit]).all() and np.isposinf(out["z"][ok & ~hit]).all()
    for name in ("depth", "z"):
        np.testing.assert_allclose(out[name][hit], ref[name][hit], rtol=2e-6, err_msg=name)
    np.testing.assert_allclose(out["normal"][hit], ref["normal"][hit], atol=1.5e-6)
    np.testing.assert_allclose(np.linalg.norm(out["normal"][hit], axis=-1), 1.0, atol=1e-6)
    scale = np.linalg.norm(ref["position"][hit], axis=-1, keepdims=True)
    assert np.all(np.abs(out["position"][hit] - ref["position"][hit]) <= 2e-6 * scale)
    np.testing.assert_allclose(out["albedo"][hit], ref["albedo"][hit], atol=4e-7)
    assert (out["normal"][ok & ~hit] == 0).all() and (out["albedo"][ok & ~hit] == 0).all()
    assert (out["motion"] == 0).all()  # nothing moves
