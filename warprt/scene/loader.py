"""TOML scene files: parse, check every table and field, and build the description objects.

A scene file states only what differs from the defaults (see docs/scene-format.md)::

    [camera]
    eye = [0, 1, 5]

    [materials.red]
    kd = [0.8, 0.1, 0.1]

    [[shapes]]
    type = "sphere"
    material = "red"

    [[lights]]
    type = "point"
    position = [2, 4, 3]

Errors name the file, the field (``shapes[1].radius``) and the problem.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import fields
from typing import Any, Mapping

from ..errors import SceneError
from .description import LIGHT_TYPES, SHAPE_TYPES, Animation, Camera, DepthSensor, Material, RenderSettings, Scene
TOP_LEVEL = {"camera", "render", "world", "materials", "shapes", "lights", "animation", "depth_sensor"}
WORLD_FIELDS = {"ambient", "background"}
# [[shapes]] type = "assets": a glTF/GLB file (or any multi-object file trimesh reads) loaded by
# warprt.scene.assets.load_assets into one mesh shape per node, with its materials
ASSET_FIELDS = ("file", "transform", "smooth", "material", "prefix", "degenerate", "unsupported")


def _assets(item: Mapping[str, Any], where: str, base_dir: str, materials: dict) -> list[Any]:
    """Expand an ``assets`` entry into its mesh shapes; its materials go into ``materials``."""
    from .assets import load_assets

    unknown = sorted(set(item) - set(ASSET_FIELDS) - {"type"})
    if unknown:
        raise SceneError(f"unknown field(s) {', '.join(unknown)}; expected some of: {', '.join(ASSET_FIELDS)}", where)
    file = item.get("file")
    if not isinstance(file, str) or not file:
        raise SceneError(f"expected the path of a glTF/GLB file, got {file!r}", f"{where}.file")
    path = os.path.join(base_dir, file)
    if not os.path.isfile(path):
        raise SceneError(f"asset file not found: {file!r} (looked in {os.path.abspath(path)!r})", f"{where}.file")
    kwargs = {k: item[k] for k in ASSET_FIELDS if k in item and k != "file"}
    try:
        shapes, mats = load_assets(os.path.abspath(path), **kwargs)
    except SceneError as e:
        raise e.within(where) from None
    for name, m in mats.items():
        if name in materials and materials[name] != m:
            raise SceneError(f"the asset's material {name!r} clashes with another material of that name; set "
                             f"prefix", f"{where}.prefix")
        materials[name] = m
    return shapes


def _texture_paths(table: Any, base_dir: str, where: str) -> Any:
    """A material table with its textures' image files resolved against the scene file's folder
    (``texture = "wood.png"`` or ``texture = {file = "wood.png", ...}``)."""
    if not isinstance(table, Mapping):
        return table
    out = dict(table)
    for name in Material.TEXTURE_FIELDS:
        value = out.get(name)
        file = value if isinstance(value, str) else value.get("file") if isinstance(value, Mapping) else None
        if not isinstance(file, str) or not file:
            continue
        path = os.path.join(base_dir, file)
        if not os.path.isfile(path):
            field = f"{where}.{name}" + (".file" if isinstance(value, Mapping) else "")
            raise SceneError(f"texture file not found: {file!r} (looked in {os.path.abspath(path)!r})", field)
        out[name] = os.path.abspath(path) if isinstance(value, str) else {**value, "file": os.path.abspath(path)}
    return out


def _make(cls: type, table: Any, where: str, skip: tuple[str, ...] = ()) -> Any:
    if not isinstance(table, Mapping):
        raise SceneError(f"expected a table, got {table!r}", where)
    allowed = [f.name for f in fields(cls) if f.name not in skip]
    unknown = sorted(set(table) - set(allowed) - set(skip))
    if unknown:
        raise SceneError(f"unknown field(s) {', '.join(unknown)}; expected some of: {', '.join(allowed)}", where)
    kwargs = {k: v for k, v in table.items() if k not in skip}
    try:
        return cls(**kwargs)
    except SceneError as e:
        raise e.within(where) from None


def _typed_list(items: Any, kinds: dict[str, type], where: str, base_dir: str,
                asset_materials: dict | None = None) -> list[Any]:
    if not isinstance(items, list):
        raise SceneError(f"expected an array of tables ([[{where}]]), got {type(items).__name__}", where)
    out = []
    for i, item in enumerate(items):
        loc = f"{where}[{i}]"
        if not isinstance(item, Mapping):
            raise SceneError(f"expected a table, got {item!r}", loc)
        kind = item.get("type")
        if asset_materials is not None and kind == "assets":
            out.extend(_assets(item, loc, base_dir, asset_materials))
            continue
        if not isinstance(kind, str) or kind not in kinds:
            names = [*kinds, "assets"] if asset_materials is not None else list(kinds)
            raise SceneError(f"type must be one of {', '.join(repr(k) for k in names)}, got {kind!r}", f"{loc}.type")
        item = dict(item)
        if kind == "mesh" and kinds is SHAPE_TYPES and isinstance(item.get("file"), str):
            path = os.path.join(base_dir, item["file"])
            if not os.path.isfile(path):
                raise SceneError(f"mesh file not found: {item['file']!r} (looked in {os.path.abspath(path)!r})",
                                 f"{loc}.file")
            item["file"] = os.path.abspath(path)
        out.append(_make(kinds[kind], item, loc, skip=("type",)))
    return out


def parse_scene(data: Mapping[str, Any], source: str | None = None, base_dir: str = ".") -> Scene:
    """Build a :class:`Scene` from parsed TOML data (a dict)."""
    try:
        unknown = sorted(set(data) - TOP_LEVEL)
        if unknown:
            raise SceneError(f"unknown table(s) {', '.join(unknown)}; expected some of: {', '.join(sorted(TOP_LEVEL))}",
                             unknown[0])
        camera = _make(Camera, data.get("camera", {}), "camera")
        render = _make(RenderSettings, data.get("render", {}), "render")
        animation = _make(Animation, data.get("animation", {}), "animation")
        sensor = _make(DepthSensor, data["depth_sensor"], "depth_sensor") if "depth_sensor" in data else None
        world = data.get("world", {})
        if not isinstance(world, Mapping):
            raise SceneError("expected a table", "world")
        bad = sorted(set(world) - WORLD_FIELDS)
        if bad:
            raise SceneError(f"unknown field(s) {', '.join(bad)}; expected some of: ambient, background", "world")
        mats_in = data.get("materials", {})
        if not isinstance(mats_in, Mapping):
            raise SceneError("expected tables [materials.NAME]", "materials")
        materials = {name: _make(Material, _texture_paths(m, base_dir, f"materials.{name}"), f"materials.{name}")
                     for name, m in mats_in.items()}
        asset_materials: dict = {}
        shapes = _typed_list(data.get("shapes", []), SHAPE_TYPES, "shapes", base_dir, asset_materials)
        for name, m in asset_materials.items():
            if name in materials:
                raise SceneError(f"an asset's material {name!r} clashes with [materials.{name}]; set the asset's "
                                 f"prefix", "shapes")
            materials[name] = m
        lights = _typed_list(data.get("lights", []), LIGHT_TYPES, "lights", base_dir)
        kwargs = {k: world[k] for k in WORLD_FIELDS if k in world}
        try:
            return Scene(camera=camera, shapes=tuple(shapes), materials=materials, lights=tuple(lights),
                         render=render, animation=animation, source=source, depth_sensor=sensor, **kwargs)
        except SceneError as e:
            raise (e if e.field and e.field.split(".")[0].split("[")[0] in TOP_LEVEL else e.within("world")) from None
    except SceneError as e:
        raise e.within(source=source) from None


def load_scene(path: str | os.PathLike) -> Scene:
    """Read a TOML scene file. Relative mesh paths are resolved against the file's folder."""
    if not isinstance(path, (str, os.PathLike)):
        raise SceneError(f"load_scene expects a file path (str or os.PathLike), got {type(path).__name__}")
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise SceneError("scene file not found", source=path) from None
    except IsADirectoryError:
        raise SceneError("is a directory, not a scene file", source=path) from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"not valid TOML: {_with_line(e, path)}", source=path) from None
    except UnicodeDecodeError as e:
        line = e.object[:e.start].count(b"\n") + 1
        raise SceneError(f"not UTF-8 text (byte 0x{e.object[e.start]:02x} on line {line}); TOML scene files must be "
                         f"UTF-8", source=path) from None
    except OSError as e:
        raise SceneError(f"cannot read the scene file: {e.strerror or e}", source=path) from None
    return parse_scene(data, source=path, base_dir=os.path.dirname(os.path.abspath(path)))


def _with_line(error: Exception, path: str | None = None, text: str | None = None) -> str:
    """tomllib's message, with the line number added where it says only "end of document"."""
    msg = str(error)
    if "line" in msg:
        return msg
    try:
        if text is None and path is not None:
            with open(path, encoding="utf-8", errors="replace") as f:
                text = f.read()
        n = max(1, (text or "").rstrip("\n").count("\n") + 1)
    except OSError:
        return msg
    return f"{msg} (line {n}, the last)"


def scene_from_string(text: str, base_dir: str = ".", source: str = "<string>") -> Scene:
    """Parse a scene from TOML text (handy in tests and notebooks)."""
    if not isinstance(text, str):
        raise SceneError(f"scene_from_string expects TOML text (a str), got {type(text).__name__}"
                         + ("; for a file use load_scene" if isinstance(text, os.PathLike) else ""))
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"not valid TOML: {_with_line(e, text=text)}", source=source) from None
    return parse_scene(data, source=source, base_dir=base_dir)
