"""warprt: a recursive and distribution ray tracer whose kernels are Python compiled by NVIDIA Warp.

Quick use::

    import warprt
    scene = warprt.load_scene("scenes/showcase.toml")
    image = warprt.render(scene, spp=16)          # (H, W, 3) float32 linear radiance
    warprt.save_image(image, "out/showcase.png")

The same kernels run on the CPU (tiles over a thread pool) and on CUDA (``device="cuda"``).
"""

from .records import Features
from .errors import RenderError, SceneError
from .image import check_output, read_exr, save_image
from .query import camera_rays, trace_rays
from . import animation, fast
from .scene.assets import load_assets
from .render import Renderer, RenderResult, render
from .worlds import BatchRenderer, BatchResult
from .scene import (
    Animation, Box, Camera, Capsule, Cylinder, DirectionalLight, Disk, DiskLight, Material, Mesh, Plane, PointLight, Rectangle, RectLight, RenderSettings, Scene,
    Sphere, SphereLight, Transform, load_scene, parse_scene, scene_from_string,
)

__version__ = "0.1.0"

__all__ = [
    "Animation", "BatchRenderer", "BatchResult", "Box", "Camera", "Capsule", "Cylinder", "DirectionalLight", "Disk", "DiskLight", "Features", "Material", "Mesh", "Plane", "PointLight", "Rectangle",
    "RectLight", "RenderError", "RenderResult", "RenderSettings", "Renderer", "Scene", "SceneError", "Sphere",
    "SphereLight", "Transform", "load_scene", "parse_scene", "check_output", "read_exr", "render", "save_image",
    "scene_from_string", "camera_rays", "trace_rays", "load_assets",
]
