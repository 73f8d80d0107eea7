"""warprt: a recursive and distribution ray tracer whose kernels are Python compiled by NVIDIA Warp.

Quick use::

    import warprt
    scene = warprt.load_scene("scenes/showcase.toml")
    image = warprt.render(scene, spp=16)          # (H, W, 3) float32 linear radiance
    warprt.save_image(image, "out/showcase.png")
    plt.imshow(warprt.linear_to_srgb(image))      # the sRGB view of the linear image

The same kernels run on the CPU (tiles over a thread pool) and on CUDA (``device="cuda"``).
"""

import importlib
import sys
import types

__version__ = "0.1.0"

# the public names and the modules that define them, imported on first use (PEP 562): importing
# warprt itself loads neither Warp nor NumPy, so the command line can take charge of Ctrl-C before
# the second or so that they take to load, and a pytest run that never renders does not pay it
_EXPORTS = {
    "Features": "records", "RenderError": "errors", "SceneError": "errors",
    "check_output": "image", "read_exr": "image", "save_image": "image",
    "camera_rays": "query", "trace_rays": "query", "load_assets": "scene.assets",
    "Renderer": "render", "RenderResult": "render",
    "BatchRenderer": "worlds", "BatchResult": "worlds", "FrameResult": "results", "RenderLayers": "results",
    "linear_to_srgb": "colour", "srgb_to_linear": "colour", "look_at": "poses", "Texture": "scene.texture",
    **{name: "scene" for name in (
        "Animation", "Box", "Camera", "Capsule", "Cylinder", "DepthSensor", "DirectionalLight", "Disk", "DiskLight", "Material",
        "Mesh", "Plane", "PointLight", "Rectangle", "RectLight", "RenderSettings", "Scene", "Sphere", "SphereLight",
        "Transform", "load_scene", "parse_scene", "scene_from_string")},
}
_SUBMODULES = {"animation", "fast"}

__all__ = [
    "Animation", "BatchRenderer", "BatchResult", "Box", "Camera", "Capsule", "Cylinder", "DirectionalLight", "Disk", "DiskLight", "Features", "Material", "Mesh", "Plane", "PointLight", "Rectangle",
    "RectLight", "RenderError", "RenderResult", "RenderSettings", "Renderer", "Scene", "SceneError", "Sphere",
    "SphereLight", "Transform", "load_scene", "parse_scene", "check_output", "read_exr", "render", "save_image",
    "scene_from_string", "camera_rays", "trace_rays", "load_assets", "FrameResult", "RenderLayers", "linear_to_srgb",
    "srgb_to_linear", "DepthSensor", "look_at", "Texture",
]


def __getattr__(name: str):
    if name in _EXPORTS:
        if _EXPORTS[name] not in ("errors", "colour", "poses"):  # (those need no Warp)
            importlib.import_module("._warp", __name__)  # Warp initialised quietly, with warprt's settings
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    elif not name.startswith("__"):  # a submodule (warprt.image, warprt.animation ...), as before
        try:
            value = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS) | _SUBMODULES | {"render"})


class _Package(types.ModuleType):
    """The package's module type: ``warprt.render`` is the function, although the module
    ``warprt/render.py`` shares its name (the import system records each submodule on its
    package as it loads; that record is dropped for this one name)."""

    @property
    def render(self):
        from .render import render

        return render

    @render.setter
    def render(self, value) -> None:
        pass


sys.modules[__name__].__class__ = _Package
