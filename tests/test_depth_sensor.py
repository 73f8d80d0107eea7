"""Depth sensor models (warprt.sensor, warprt.DepthSensor) against their formulas.

The sensor kernel runs on synthetic AOVs first (every pixel at a known depth Z, or seeing its
surface at a known angle), where the statistics are exact:

* stereo noise: the disparity error f·b/Z' - f·b/Z is N(0, σ_d²): its mean and variance match
  within 4σ of their estimators (σ_d/√N, σ_d²·√(2/(N-1))); in depth, the standard deviation at
  each Z matches the first-order σ_Z = Z²·σ_d/(f·b) within 4σ of its estimator plus the
  second-order term (relative 3·(σ_Z/Z)², here below 1e-4), and the mean of Z' - Z within 4σ of its
  estimator plus the second-order bias Z·(σ_Z/Z)²;
* dropouts: the fraction dropped at angle θ is binomial with p(θ) = clamp((θ - start) / (end -
  start), 0, 1): within 4·√(p(1 - p)/N), exactly none below start and all from end on;
* range limits and quantisation: exact (float32 rounding of f·b/d).

Then renders: a single render and a batch (through the Newton bridge, on its test model and
kernels) give the sensor outputs next to the exact ones, which they leave unchanged, with the same
noise for the same seed.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import warp as wp

import warprt
from warprt.errors import RenderError, SceneError
from warprt.sensor import apply_depth_sensor

from tests.test_aovs import scene as aov_scene

N = 200_000  # pixels per known depth or angle
F, B, SIGMA = 600.0, 0.05, 0.2  # focal length (px), baseline (m), disparity noise (px)


def run(model, z, normal=None, position=None, eye=(0.0, 0.0, 0.0), seed=0, depth=None, device="cpu"):
    """The sensor outputs of flat arrays (host numpy), all pixels seen from one eye."""
    z = np.asarray(z, np.float32)
    n = len(z)
    aovs = {"z": wp.array(z, dtype=float, device=device),
            "depth": wp.array(z if depth is None else np.asarray(depth, np.float32), dtype=float, device=device)}
    if normal is not None:
        aovs["normal"] = wp.array(np.asarray(normal, np.float32), dtype=wp.vec3, device=device)
        aovs["position"] = wp.array(np.asarray(position, np.float32), dtype=wp.vec3, device=device)
    eyes = wp.array(np.array([[*eye, 0, 0, 0, 1]], np.float32), dtype=wp.transform, device=device)
    out = apply_depth_sensor(model, aovs, eyes, n, seed)
    return {k: v.numpy().copy() for k, v in out.items()}


def test_stereo_noise_has_the_disparity_error_and_sigma_z_grows_as_z_squared():
    model = warprt.DepthSensor(baseline=B, focal_length=F, disparity_sigma=SIGMA)
    zs = (1.0, 2.0, 4.0, 8.0)
    z = np.repeat(np.array(zs, np.float32), N)
    out = run(model, z, seed=11)["sensor_z"].astype(np.float64).reshape(len(zs), N)
    assert np.isfinite(out).all()
    for k, z0 in enumerate(zs):
        z0 = float(np.float32(z0))
        err = F * B / out[k] - F * B / z0  # the disparity error, N(0, SIGMA²)
        assert abs(err.mean()) < 4 * SIGMA / math.sqrt(N)
        assert abs(err.var(ddof=1) - SIGMA ** 2) < 4 * SIGMA ** 2 * math.sqrt(2 / (N - 1))
        sigma_z = z0 ** 2 * SIGMA / (F * B)  # first order
        assert sigma_z == pytest.approx(model.sigma_z(z0))
        rel = sigma_z / z0
        std = out[k].std(ddof=1)
        assert abs(std / sigma_z - 1) < 4 / math.sqrt(2 * (N - 1)) + 3 * rel ** 2
        assert abs(out[k].mean() - z0 - z0 * rel ** 2) < 4 * sigma_z / math.sqrt(N) + z0 * rel ** 3 * 10


def test_quantised_disparity_and_range_limits_are_exact():
    model = warprt.DepthSensor(baseline=B, focal_length=F, disparity_step=0.125, min_range=0.5, max_range=6.0,
                               invalid="zero")
    z = np.float32(np.linspace(0.2, 8.0, 5001))
    got = run(model, z)["sensor_z"]
    d = np.floor(F * B / z.astype(np.float64) / 0.125 + 0.5) * 0.125
    want = F * B / d
    inside = (want >= 0.5) & (want <= 6.0)
    np.testing.assert_allclose(got[inside], want[inside], rtol=3e-7)
    assert (got[~inside] == 0.0).all()  # invalid = "zero"
    # the limits themselves, and one float32 step beyond them
    plain = warprt.DepthSensor(min_range=0.5, max_range=6.0)
    lo, hi = np.float32(0.5), np.float32(6.0)
    edge = np.array([np.nextafter(lo, 0), lo, np.nextafter(lo, 1), np.nextafter(hi, 0), hi, np.nextafter(hi, 7),
                     np.inf], np.float32)
    out = run(plain, edge, depth=edge * 1.5)
    np.testing.assert_array_equal(np.isnan(out["sensor_z"]), [True, False, False, False, False, True, True])
    ok = ~np.isnan(out["sensor_z"])
    np.testing.assert_array_equal(out["sensor_z"][ok], edge[ok])  # no noise: the depth itself
    np.testing.assert_array_equal(out["sensor_depth"][ok], (edge * np.float32(1.5))[ok])
    assert np.isnan(out["sensor_depth"][~ok]).all()


def test_dropout_fraction_follows_the_documented_probability():
    model = warprt.DepthSensor(dropout_start=50.0, dropout_end=80.0)
    angles = np.array([20.0, 49.0, 55.0, 65.0, 72.5, 79.0, 80.5, 89.0])
    th = np.radians(np.repeat(angles, N // 4))
    # the surface at the origin of the eye's frame, turned by θ from the view ray
    normal = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=1)
    position = np.zeros_like(normal)
    out = run(model, np.full(len(th), 2.0, np.float32), normal, position, eye=(0.0, 0.0, 2.0), seed=3)
    dropped = np.isnan(out["sensor_z"]).reshape(len(angles), -1).mean(axis=1)
    p = np.clip((angles - 50.0) / 30.0, 0.0, 1.0)
    np.testing.assert_allclose(model.dropout_probability(angles), p)
    n = N // 4
    for a, frac, pk in zip(angles, dropped, p):
        if pk in (0.0, 1.0):
            assert frac == pk, a
        else:
            assert abs(frac - pk) < 4 * math.sqrt(pk * (1 - pk) / n), (a, frac, pk)
    kept = out["sensor_z"][~np.isnan(out["sensor_z"])]
    assert (kept == np.float32(2.0)).all()  # dropouts alone change nothing else


def test_the_same_seed_gives_the_same_noise_and_another_seed_other_noise():
    model = warprt.DepthSensor(baseline=B, focal_length=F, disparity_sigma=SIGMA, dropout_start=30, dropout_end=80)
    k = 20_000
    z = np.float32(np.linspace(0.5, 5.0, k))
    th = np.radians(np.linspace(0, 89, k))
    normal = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=1)
    args = (model, z, normal, np.zeros_like(normal))
    a, b, c = run(*args, eye=(0, 0, 1), seed=5), run(*args, eye=(0, 0, 1), seed=5), run(*args, eye=(0, 0, 1), seed=6)
    np.testing.assert_array_equal(a["sensor_z"], b["sensor_z"])
    assert np.mean(a["sensor_z"] != c["sensor_z"]) > 0.9


def test_cuda_gives_the_cpu_statistics(cuda_device):
    model = warprt.DepthSensor(baseline=B, focal_length=F, disparity_sigma=SIGMA)
    z = np.full(N, 3.0, np.float32)
    cpu, gpu = run(model, z, seed=2)["sensor_z"], run(model, z, seed=2, device=cuda_device)["sensor_z"]
    np.testing.assert_allclose(gpu, cpu, rtol=1e-5)  # the same draws; log/cos may round differently


@pytest.mark.parametrize("fields, field", [
    (dict(disparity_sigma=0.1, focal_length=600.0), "baseline"),
    (dict(disparity_step=0.1, baseline=0.05), "focal_length"),
    (dict(baseline=-1.0), "baseline"),
    (dict(disparity_sigma=-0.1), "disparity_sigma"),
    (dict(min_range=2.0, max_range=1.0), "max_range"),
    (dict(dropout_start=60.0, dropout_end=50.0), "dropout_end"),
    (dict(dropout_end=95.0), "dropout_end"),
    (dict(invalid="none"), "invalid"),
    (dict(basline=0.05), "basline"),
])
def test_bad_sensor_parameters_name_the_field(fields, field):
    with pytest.raises(SceneError) as e:
        warprt.DepthSensor(**fields)
    assert e.value.field == field


def test_scene_files_take_the_python_field_names():
    text = """
[camera]
width = 8
height = 6

[depth_sensor]
baseline = 0.05
focal_length = 600
disparity_sigma = 0.08
min_range = 0.3
max_range = 10
dropout_start = 70
dropout_end = 85
invalid = "zero"
"""
    scene = warprt.scene_from_string(text)
    assert scene.depth_sensor == warprt.DepthSensor(baseline=0.05, focal_length=600, disparity_sigma=0.08,
                                                    min_range=0.3, max_range=10, dropout_start=70, dropout_end=85,
                                                    invalid="zero")
    with pytest.raises(SceneError, match="depth_sensor.focal_length"):
        warprt.scene_from_string("[depth_sensor]\nbaseline = 0.05\ndisparity_sigma = 0.1\n")
    with pytest.raises(SceneError, match="depth_sensor.*baseline_m"):
        warprt.scene_from_string("[depth_sensor]\nbaseline_m = 0.05\n")


# --- renders: the scene of tests/test_aovs.py (its kernel), a wall facing the camera --------------

def scene(sensor):
    return dataclasses.replace(aov_scene(), depth_sensor=sensor)


def test_a_render_gives_the_sensor_outputs_next_to_the_exact_depth():
    noisy = warprt.DepthSensor(baseline=B, focal_length=F, disparity_sigma=0.5, max_range=4.2)
    r = warprt.Renderer(scene(noisy))
    a = r.render(seed=4, aovs=["z", "depth", "sensor_z", "sensor_depth"])
    assert list(a.aovs) == ["z", "depth", "sensor_z", "sensor_depth"]
    plain = warprt.Renderer(scene(None)).render(seed=4, aovs=["z", "depth"])
    np.testing.assert_array_equal(a.image, plain.image)  # the sensor changes no exact output
    np.testing.assert_array_equal(a.aovs["z"], plain.aovs["z"])
    z, sz = a.aovs["z"], a.aovs["sensor_z"]
    valid = ~np.isnan(sz)
    assert valid.sum() > 50 and (~valid).sum() > 10  # the sky and the far floor are invalid
    assert (sz[valid] <= 4.2).all() and (~np.isfinite(z[~valid]) | (z[~valid] > 3.5)).all()
    np.testing.assert_allclose(a.aovs["sensor_depth"][valid] / sz[valid], a.aovs["depth"][valid] / z[valid],
                               rtol=1e-6)
    err = (F * B / sz - F * B / z)[valid]
    assert 0.2 < err.std() < 1.0 and abs(err.mean()) < 0.5  # σ_d 0.5 on ~100 pixels (loose: plumbing)
    # the same seed: the same noise; only what is asked for comes back
    b = r.render(seed=4, aovs=["sensor_z"])
    assert list(b.aovs) == ["sensor_z"]
    np.testing.assert_array_equal(b.aovs["sensor_z"], sz)
    assert not np.array_equal(np.nan_to_num(r.render(seed=5, aovs=["sensor_z"]).aovs["sensor_z"]), np.nan_to_num(sz))
    layers = warprt.render(scene(noisy), seed=4, aovs=["sensor_z"])
    np.testing.assert_array_equal(layers["sensor_z"], sz)


def test_sensor_outputs_need_a_sensor_model():
    with pytest.raises(RenderError, match="sensor_z.*DepthSensor"):
        warprt.Renderer(scene(None)).render(aovs=["sensor_z"])
    with pytest.raises(RenderError, match="unknown AOV"):
        warprt.Renderer(scene(None)).render(aovs=["sensor_zz"])


def test_sensor_noise_is_the_same_for_any_thread_count_or_slices_and_stays_on_the_device():
    noisy = warprt.DepthSensor(baseline=B, focal_length=F, disparity_sigma=0.5, dropout_start=40, dropout_end=80)
    r = warprt.Renderer(scene(noisy))
    a = r.render(seed=2, aovs=["sensor_z", "sensor_depth"], workers=1)
    b = r.render(seed=2, aovs=["sensor_z", "sensor_depth"], workers=2, slices=5, pass_spp=3)
    c = r.render(seed=2, aovs=["sensor_z", "sensor_depth"], as_warp=True)
    for name in ("sensor_z", "sensor_depth"):
        np.testing.assert_array_equal(a.aovs[name], b.aovs[name])
        assert isinstance(c.aovs[name], wp.array) and c.aovs[name].shape == (12, 16)
        np.testing.assert_array_equal(c.aovs[name].numpy(), a.aovs[name])


def test_the_command_line_writes_the_sensor_outputs_of_a_scene_file(tmp_path, capsys):
    from warprt.cli import main

    text = (f"[camera]\neye = [0, 1.5, 4]\nlook_at = [0, 0.5, 0]\nfov = 40\nwidth = 16\nheight = 12\n"
            f"[render]\nspp = 2\n[[shapes]]\ntype = \"plane\"\nnormal = [0.1, 1, 0]\n"
            f"[[shapes]]\ntype = \"rectangle\"\ncorner = [0.05, 0, -0.5]\nedge1 = [0, 1.2, 0]\nedge2 = [3, 0, 0]\n"
            f"[[shapes]]\ntype = \"sphere\"\ncenter = [-0.6, 0.6, 0.3]\nradius = 0.45\n"
            f"[[lights]]\ntype = \"point\"\nposition = [1, 4, 3]\n"
            f"[depth_sensor]\nmax_range = 4.0\ninvalid = \"zero\"\n")
    (tmp_path / "s.toml").write_text(text)
    out = tmp_path / "s.exr"
    assert main(["render", str(tmp_path / "s.toml"), "-o", str(out), "--aovs", "z,sensor_z", "--no-progress"]) == 0
    _, _, layers = warprt.read_exr(out, layers=True)
    z, sz = layers["z"], layers["sensor_z"]
    inside = np.isfinite(z) & (z <= 4.0)
    np.testing.assert_array_equal(sz[inside], z[inside])  # no noise: the exact depth within the range
    assert (sz[~inside] == 0).all() and (~inside).any()


def test_an_orthographic_cameras_dropouts_judge_the_angle_to_its_parallel_rays():
    """Parallel rays straight down on a floor meet it head-on everywhere (θ = 0), though the
    line from the image's corners to the camera's centre is 86° off the normal; on a floor
    tilted 45° every pixel sees θ = 45°. With dropouts from 20° (certain from 21°) the first
    keeps every pixel, the second none, in single renders and batches."""
    sensor = warprt.DepthSensor(dropout_start=20.0, dropout_end=21.0)
    cam = warprt.Camera(model="orthographic", fx=1.6, eye=(0, 1, 0), look_at=(0, 0, 0), up=(0, 0, -1),
                        width=32, height=32)  # 20 × 20 scene units seen from 1 unit above the floor
    high = warprt.Camera(model="orthographic", fx=1.6, eye=(0, 20, 0), look_at=(0, 0, 0), up=(0, 0, -1),
                         width=32, height=32)

    def floor(normal):  # (the tilted floor, seen from higher up, lies below the camera everywhere)
        return warprt.Scene(camera=cam if normal == (0, 1, 0) else high, shapes=(warprt.Plane(point=(0, 0, 0), normal=normal),),
                            render=warprt.RenderSettings(spp=1, adaptive=False), depth_sensor=sensor)

    for normal, kept in (((0, 1, 0), 1.0), ((0, 1, 1), 0.0)):
        single = warprt.Renderer(floor(normal)).render(aovs=["z", "sensor_z"]).aovs
        assert np.isfinite(single["z"]).all()
        assert np.isfinite(single["sensor_z"]).mean() == kept
        batch = warprt.BatchRenderer(floor(normal)).render(aovs=["sensor_z"]).frame(0, 0).aovs
        assert np.isfinite(batch["sensor_z"]).mean() == kept
