"""Scene descriptions: dataclasses (Python API) and the TOML loader that builds the same objects."""

from .description import (
    Animation, Box, Camera, Capsule, Cylinder, DepthSensor, DirectionalLight, Disk, DiskLight, Material, Mesh, Plane, PointLight, Rectangle, RectLight, RenderSettings,
    Scene, Sphere, SphereLight,
)
from .transform import Transform
from .loader import load_scene, parse_scene, scene_from_string

__all__ = [
    "Animation", "Box", "Camera", "Capsule", "Cylinder", "DepthSensor", "DirectionalLight", "Disk", "DiskLight", "Material", "Mesh", "Plane", "PointLight", "Rectangle", "RectLight",
    "RenderSettings", "Scene", "Sphere", "SphereLight", "Transform", "load_scene", "parse_scene",
    "scene_from_string",
]
