"""The example scripts run as a user would run them (a fresh Python process), at a small size, and
the README's quick start names the two set-up commands. (The code blocks of README.md and docs/
are run by test_docs.py.)"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import warprt

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
W, H = 48, 32


def run_example(name: str, out_dir: Path, *extra: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)  # WARP_CACHE_PATH (set by conftest.py) is inherited: kernels are shared
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), str(out_dir), "--width", str(W), "--height", str(H),
                           *extra], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{name} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    return proc


def png_size(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        return im.size


def test_build_scene_example_writes_png_and_exr(tmp_path):
    out = tmp_path / "images"  # a folder that does not exist yet: the script creates it
    proc = run_example("build_scene.py", out, "--spp", "1")
    assert png_size(out / "build_scene.png") == (W, H)
    rgb, header = warprt.read_exr(out / "build_scene.exr")
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.float32
    assert np.isfinite(rgb).all() and rgb.mean() > 0.0
    assert "stack overflows: 0" in proc.stdout
    assert "Mrays/s" in proc.stdout


def test_ray_queries_example_writes_depth_images(tmp_path):
    proc = run_example("ray_queries.py", tmp_path, "--spp", "2")
    assert png_size(tmp_path / "depth.png") == (W, H)
    assert png_size(tmp_path / "lidar.png") == (W, H)
    depth, _ = warprt.read_exr(tmp_path / "depth.exr")
    assert depth.shape == (H, W, 3)
    assert np.isfinite(depth).any() and np.isposinf(depth).any()  # ground, and sky (inf: no return)
    points = np.load(tmp_path / "lidar_points.npy")
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) > 0
    assert "depth camera:" in proc.stdout and "lidar:" in proc.stdout


def test_readme_quick_start_names_the_two_commands():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    start = readme.index("## Quick start")
    end = readme.find("\n## ", start + 1)
    quick = readme[start:end if end > 0 else None]
    assert "make render" in quick
    assert "make test" in quick


@pytest.mark.parametrize("name", ["build_scene.py", "ray_queries.py", "newton_sim.py", "robot_camera.py"])
def test_examples_document_their_small_size_flags(name):
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0
    for flag in ("--width", "--height", "--spp"):
        assert flag in proc.stdout


def test_make_doc_images_writes_every_image_at_a_fifth_of_the_size(tmp_path):
    """examples/make_doc_images.py with --scale 0.2 and one sample per pixel: every image it
    lists is written (into a folder it creates), at a fifth of its documented size, and shows
    something. At full size the script takes about 45 s; this small, a few seconds once the
    kernels are cached."""
    out = tmp_path / "images"
    listed = subprocess.run([sys.executable, str(EXAMPLES / "make_doc_images.py"), "--list"], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert listed.returncode == 0, listed.stderr
    names = [line.split(":")[0] for line in listed.stdout.splitlines() if line.strip()]
    assert len(names) >= 10 and all(n.endswith(".png") for n in names)
    proc = subprocess.run([sys.executable, str(EXAMPLES / "make_doc_images.py"), str(out), "--scale", "0.2",
                           "--max-spp", "1"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"make_doc_images.py failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    # single renders at a fifth of their size (showcase.toml is reduced to 320x180 first)
    assert png_size(out / "showcase.png") == (64, 36)
    assert png_size(out / "mirror.png") == (48, 36)
    for name in names:
        with Image.open(out / name) as im:
            mean = np.asarray(im.convert("RGB")).mean()
        # Mean 8-bit value: these renders measure 63-188 at this size; with every render black
        # the single images are 0 and the comparison sheets (dark background, white captions) at
        # most 36, so 50 separates a missing or black panel from a real one.
        assert mean > 50, f"{name}: mean 8-bit value {mean:.1f}, a render is black"


def test_make_doc_images_documents_its_quick_options():
    proc = subprocess.run([sys.executable, str(EXAMPLES / "make_doc_images.py"), "--help"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0
    for flag in ("--scale", "--max-spp", "--only", "--list"):
        assert flag in proc.stdout
    bad = subprocess.run([sys.executable, str(EXAMPLES / "make_doc_images.py"), "--scale", "2"], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and "--scale must be in (0, 1]" in bad.stderr


@pytest.mark.xdist_group("newton examples")  # one worker: the second finds Newton's kernels compiled
def test_newton_sim_example_writes_a_sequence_per_world_and_camera(tmp_path):
    pytest.importorskip("newton")
    proc = run_example("newton_sim.py", tmp_path, "--spp", "1", "--steps", "2", "--worlds", "2")
    names = sorted(p.name for p in tmp_path.glob("*.png"))
    assert names == [f"w{w}_c{c}_{f:04d}.png" for w in range(2) for c in range(2) for f in range(2)]
    assert png_size(tmp_path / names[0]) == (W, H)
    # the counters line: nothing rebuilt, compiled or copied after the first frame
    line = next(l for l in proc.stdout.splitlines() if l.startswith("counters"))
    first, last = line.split(" after the last ")
    assert first.split("first frame ")[1].rstrip(",") == last


@pytest.mark.xdist_group("newton examples")  # one worker: the second finds Newton's kernels compiled
def test_robot_camera_example_writes_colour_and_noisy_depth_per_episode_world_and_step(tmp_path):
    pytest.importorskip("newton")
    proc = run_example("robot_camera.py", tmp_path, "--spp", "1", "--steps", "2", "--worlds", "2", "--episodes", "2")
    stems = [f"e{e}_w{w}_{s:03d}" for e in range(2) for w in range(2) for s in range(2)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{stem}{ext}" for stem in stems for ext in (".exr", ".png", "_depth.png"))
    assert png_size(tmp_path / f"{stems[0]}.png") == (W, H) == png_size(tmp_path / f"{stems[0]}_depth.png")
    rgb, header, layers = warprt.read_exr(tmp_path / f"{stems[-1]}.exr", layers=True)
    z, sz = layers["z"], layers["sensor_z"]
    assert rgb.shape == (H, W, 3) and z.shape == sz.shape == (H, W) and "worldToCamera" in header
    valid = np.isfinite(sz)
    assert 0.1 < valid.mean() < 1.0 and (sz[valid] <= 4.0).all()  # the sensor's range, and no-value pixels
    assert np.abs(sz - z)[valid].max() > 0 and np.isfinite(z[~valid]).any()  # noise; dropped or out-of-range hits
    # two episodes draw two scenes: other colours
    first, second = (np.asarray(warprt.read_exr(tmp_path / f"e{e}_w0_000.exr")[0]) for e in (0, 1))
    assert np.abs(first - second).mean() > 1e-3
    assert "depth sensor:" in proc.stdout
    # the second episode's looks are new arrays on the device: nothing rebuilt or compiled for them
    line = next(l for l in proc.stdout.splitlines() if l.startswith("counters"))
    first, last = (ast.literal_eval(part.split("frame ")[-1]) for part in line.split(" after the last "))
    assert (first["rebuilds"], first["compiles"]) == (last["rebuilds"], last["compiles"]) == (2, 1)
