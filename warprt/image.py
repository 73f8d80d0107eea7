"""Writing images: float32 EXR (linear) and 8-bit PNG (sRGB), always atomically.

* ``.exr``: float32 linear RGB through OpenEXR (ZIP compression); extra header attributes
  (``metadata``) are stored as strings, ints or floats, e.g. the samples per pixel reached.
* ``.png``: ``metadata`` goes into text (tEXt) chunks, as strings; linear values are clamped to [0, 1] (values above 1 clip to white: no tone mapping),
  NaN becomes 0, then the sRGB transfer curve is applied and values are rounded to 8 bits.

A file is written to a temporary name in the destination folder (``.NAME.PID.XXXXXXXX.partial``,
which matches no ``*.exr``/``*.png`` glob) and renamed into place, so a crash or Ctrl-C never
leaves a truncated image, and an existing file is replaced only by a complete one. Temporary files
of the same output left by a killed process are removed by the next write. Replacing a file keeps
its permissions; writing to a symbolic link writes (atomically) to the file it points to.

A Ctrl-C during a write is held until the file is complete, then delivered
(:class:`warprt.signals.Deferred`); a second one abandons the write (no file, the old one kept).
A write that fails on a full disk, a quota or an I/O error raises :class:`warprt.errors.WriteError`
naming the file and the space free on its disk; :func:`save_image_or_fallback` then writes the
image, which is still in memory, to the system's temporary folder and says where.
:func:`check_output` imports the writer of the format (OpenEXR, Pillow) too, so nothing is
imported once the samples are done, and :func:`check_free_space` refuses, before rendering,
outputs whose disk cannot hold them.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
from typing import Mapping

import numpy as np

from .errors import RenderError, WriteError
from .signals import Deferred

FORMATS = (".exr", ".png")
EXR_MAGIC = b"\x76\x2f\x31\x01"  # the first four bytes of every OpenEXR file


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise RenderError(f"an image must have shape (H, W, 3), (H, W, 4) or (H, W), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise RenderError(f"an image must hold numbers, got dtype {a.dtype}")
    return a.astype(np.float32, copy=False)


def _srgb8(x: np.ndarray) -> np.ndarray:
    x = np.nan_to_num(np.asarray(x, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.clip(np.round(s * 255.0), 0, 255).astype(np.uint8)


SRGB_CHUNK_PIXELS = 1 << 20  # pixels converted at a time: the float temporaries stay a few MB


def linear_to_srgb8(image: np.ndarray, chunk_rows: int | None = None) -> np.ndarray:
    """Linear float to 8-bit sRGB, in chunks of rows, so the float temporaries never span the whole
    image (the output is the only full-size allocation); elementwise, so the bytes do not depend
    on the chunking."""
    image = np.asarray(image)
    if image.ndim < 2 or image.shape[0] == 0:
        return _srgb8(image)
    row = max(1, int(np.prod(image.shape[1:-1] if image.ndim > 2 else image.shape[1:])))
    rows = chunk_rows or max(1, SRGB_CHUNK_PIXELS // row)
    out = np.empty(image.shape, dtype=np.uint8)
    for r0 in range(0, image.shape[0], rows):
        out[r0:r0 + rows] = _srgb8(image[r0:r0 + rows])
    return out


def _umask() -> int:
    """The process umask, read without changing it where the system tells it (Linux's
    /proc/self/status); elsewhere by setting and restoring it, at the moment of writing."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_output(path: str | os.PathLike, create_folders: bool = False) -> str:
    """Check, before any rendering, that an image can be written to ``path``: a supported
    extension, not a folder, and a folder where a file can be created (with ``create_folders``, a
    missing folder is fine when it could be created under its nearest existing parent). Raises
    :class:`RenderError` with one line naming ``path`` and the problem; returns ``path``."""
    path = _check_path(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise RenderError(f"{path}: unsupported image format {ext or '(none)'!r}; use .exr or .png")
    import_writer(ext, path)
    if os.path.isdir(path):
        raise RenderError(f"{path}: is a folder, not an image file")
    folder = os.path.dirname(os.path.abspath(_target(path)))
    existing = folder
    while not os.path.lexists(existing):
        parent = os.path.dirname(existing)
        if parent == existing:
            break
        existing = parent
    if existing != folder and not create_folders:
        raise RenderError(f"{path}: the folder {folder!r} does not exist")
    if not os.path.isdir(existing):
        raise RenderError(f"{path}: cannot be written: {existing!r} is not a folder")
    try:  # the only sure test (permissions, read-only mounts, /proc): create a file and remove it
        fd, probe = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".probe", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise RenderError(f"{path}: cannot be written: cannot create a file in {existing!r} "
                          f"({e.strerror or e})") from None
    return path


def import_writer(ext: str, path: str = "") -> None:
    """Import the library that writes ``ext`` files now (``check_output`` does, before any
    rendering): an import is a second of work that a Ctrl-C could otherwise cut after the samples
    are done. A missing library is a :class:`RenderError` naming it."""
    try:
        if ext == ".exr":
            import OpenEXR  # noqa: F401
        elif ext == ".png":
            from PIL import Image, PngImagePlugin  # noqa: F401
    except ImportError as e:
        package = "OpenEXR" if ext == ".exr" else "Pillow"
        raise RenderError(f"{path or ext}: writing {ext} files needs {package} ({e}); "
                          f"pip install {package}") from None


# bytes per pixel of a file at most (no compression): the EXR's float32 RGB and each AOV channel
# (4 bytes, float32 or uint32), the PNG's 8-bit RGB; plus headers and the compressors' worst case
EXR_PIXEL_BYTES = 12
EXR_CHANNEL_BYTES = 4
PNG_PIXEL_BYTES = 3
FILE_OVERHEAD = 64 * 1024  # header, offset tables
INCOMPRESSIBLE = 1.01  # zlib's worst case adds a fraction of a percent to incompressible data


def estimate_file_bytes(path: str, width: int, height: int, aov_channels: int = 0) -> int:
    """The largest size a ``width`` × ``height`` image written to ``path`` can take (an EXR with
    ``aov_channels`` extra channels; a PNG holds the colour only)."""
    per_pixel = PNG_PIXEL_BYTES if os.path.splitext(os.fspath(path))[1].lower() == ".png" else \
        EXR_PIXEL_BYTES + EXR_CHANNEL_BYTES * aov_channels
    return int(per_pixel * int(width) * int(height) * INCOMPRESSIBLE) + FILE_OVERHEAD


def free_bytes(folder: str) -> int | None:
    """Bytes free to this user on the disk holding ``folder`` (its nearest existing parent), or
    None where unknown."""
    import shutil

    folder = os.path.abspath(folder or ".")
    while not os.path.isdir(folder):
        parent = os.path.dirname(folder)
        if parent == folder:
            return None
        folder = parent
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def size_text(n: int | None) -> str:
    """A byte count for a message: "512 B", "12.3 kB", "1.2 GB"; "an unknown amount" for None."""
    if n is None:
        return "an unknown amount"
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


def check_free_space(sizes: Mapping[str, int]) -> None:
    """Refuse (:class:`RenderError`, one line) before rendering when the outputs (path: largest
    size in bytes, see :func:`estimate_file_bytes`) cannot fit in the space free on their disks
    (outputs on one disk are added up; a file replaced still needs its new copy in full, the
    write being atomic). Disks whose free space is unknown are not checked."""
    by_disk: dict[object, list[str]] = {}
    free: dict[object, int | None] = {}
    for path in sizes:
        folder = os.path.dirname(os.path.abspath(_target(os.fspath(path))))
        existing = folder
        while not os.path.isdir(existing) and os.path.dirname(existing) != existing:
            existing = os.path.dirname(existing)
        try:
            disk = os.stat(existing).st_dev
        except OSError:
            continue
        by_disk.setdefault(disk, []).append(path)
        free[disk] = free_bytes(existing)
    for disk, paths in by_disk.items():
        need = sum(sizes[p] for p in paths)
        if free[disk] is not None and need > free[disk]:
            names = ", ".join(os.fspath(p) for p in paths)
            raise RenderError(f"{names}: need{'s' if len(paths) == 1 else ''} up to {size_text(need)} of disk space, "
                              f"but only {size_text(free[disk])} is free there; free some space or write elsewhere")


TEMP_SUFFIX = ".partial"


def _temp_name_pattern(name: str) -> "re.Pattern[str]":
    """The names of the temporary files written for the output ``name``: ``.NAME.PID.XXXXXXXX.partial``
    (PID of the writing process, eight random characters of ``tempfile``); they never end in the
    image's extension, so a file left by a killed process matches no ``*.exr`` or ``*.png`` glob."""
    return re.compile(r"\." + re.escape(name) + r"\.(\d+)\.[a-z0-9_]{8}" + re.escape(TEMP_SUFFIX) + r"\Z")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True  # a write of this process (another thread's) is under way
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # another user's process, or not a PID: leave its files alone
        pass
    return True


def _remove_stale_temps(folder: str, name: str) -> None:
    """Remove the temporary files of earlier writes of ``name`` in ``folder`` whose process is
    gone (killed during a write). Only files of exactly our naming are touched."""
    pattern = _temp_name_pattern(name)
    try:
        entries = os.listdir(folder)
    except OSError:
        return
    for entry in entries:
        m = pattern.match(entry)
        if m and not _pid_alive(int(m.group(1))):
            try:
                os.unlink(os.path.join(folder, entry))
            except OSError:
                pass


def _target(path: str) -> str:
    """The file really written for ``path``: through a symbolic link (chains included), its target."""
    return os.path.realpath(path) if os.path.islink(path) else path


def _atomic_write(path: str, write) -> None:
    target = _target(path)
    folder = os.path.dirname(os.path.abspath(target))
    if not os.path.isdir(folder):
        raise RenderError(f"{path}: the folder {folder!r} does not exist")
    name = os.path.basename(target)
    _remove_stale_temps(folder, name)
    try:
        old = os.stat(target)
    except OSError:
        old = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.{os.getpid()}.", suffix=TEMP_SUFFIX, dir=folder)
    except OSError as e:
        if e.errno in DISK_ERRORS:
            raise _write_error(path, folder, e) from None
        raise RenderError(f"{path}: cannot be written: cannot create a file in {folder!r} "
                          f"({e.strerror or e})") from None
    os.close(fd)
    try:
        if old is not None:
            # replacing a file: keep its permissions (and, where allowed, its owner and group)
            os.chmod(tmp, stat.S_IMODE(old.st_mode))
            if (old.st_uid, old.st_gid) != (os.geteuid(), os.getegid()):
                try:
                    os.chown(tmp, old.st_uid, old.st_gid)
                except OSError:
                    pass
        else:
            # mkstemp creates the file private (0600); give a new image the permissions a plain
            # open() would (0666 less the umask), as users of image files expect
            os.chmod(tmp, 0o666 & ~_umask())
        try:
            write(tmp)
            os.replace(tmp, target)
        except (OSError, RuntimeError) as e:  # (OpenEXR reports a failed write as a RuntimeError)
            try:
                os.unlink(tmp)  # (first: the free space reported is what is left without it)
            except OSError:
                pass
            raise _write_error(path, folder, e) from None
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


# errno values of a write that failed for lack of room or a faulty disk (the folder was writable)
DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.EROFS}


def _write_error(path: str, folder: str, e: BaseException) -> WriteError:
    """A failed write as one line naming the output and the space left on its disk."""
    reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
    for code in sorted(DISK_ERRORS):  # a library's long message that holds a system error: that error
        if os.strerror(code) in reason:
            reason = os.strerror(code)
            break
    free = free_bytes(folder)
    return WriteError(f"{path}: cannot be written: {reason} ({size_text(free)} free on its disk)", path, free)


def save_image(image, path: str | os.PathLike, metadata: Mapping[str, object] | None = None) -> None:
    """Write ``image`` (H, W, 3 linear float) to ``path``; the format follows the extension.

    ``image`` may also be a dict of layers: ``{"color": rgb, "depth": ..., "normal": ...}`` (as
    returned by ``render(..., aovs=[...])``, numpy or ``wp.array``). An EXR then holds every
    layer: warprt's AOVs under the channel names of ``aov.EXR_CHANNELS`` (``Z`` depth, ``A``
    coverage, ``N.X``..., ids as UINT holding id + 1), other layers as ``layer.X`` / ``layer.Y`` /
    ``layer.Z`` (``layer.V`` for one channel); a PNG holds the colour.

    A Ctrl-C during the write is held until the file is complete (then raised); a second one
    abandons it. A full disk, quota or I/O error raises :class:`warprt.errors.WriteError`.
    """
    with Deferred(abandon_on=2, deliver=True):
        _save_image(image, path, metadata)


def _check_path(path, what: str = "an image path") -> str:
    if not isinstance(path, (str, os.PathLike)):
        raise RenderError(f"expected {what} (str or os.PathLike), got {type(path).__name__}")
    return os.fspath(path)


def _save_image(image, path, metadata) -> None:
    path = _check_path(path)
    if metadata is not None and not isinstance(metadata, Mapping):
        raise RenderError(f"{path}: metadata must be a dict of name: value, got {type(metadata).__name__}")
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise RenderError(f"{path}: unsupported image format {ext or '(none)'!r}; use .exr or .png")
    layers = None
    if isinstance(image, Mapping):
        if "color" not in image:
            raise RenderError(f"{path}: a dict of layers needs a 'color' entry, got {sorted(image)}")
        layers = {k: v for k, v in image.items() if k != "color"}
        image = image["color"]
    a = _check_image(image)
    if ext == ".png":
        from PIL import Image

        from PIL.PngImagePlugin import PngInfo

        rgb8 = linear_to_srgb8(a[:, :, :3])
        info = PngInfo()
        for k, v in (metadata or {}).items():  # tEXt chunks, e.g. warprt:partial = true
            info.add_text(str(k), str(int(v)) if isinstance(v, bool) else str(v))
        _atomic_write(path, lambda p: Image.fromarray(rgb8, mode="RGB").save(p, format="PNG", pnginfo=info))
        return
    from .aov import AOVS

    channels = {"RGB": a[:, :, :3]}
    for name, data in (layers or {}).items():
        d = np.asarray(data.numpy() if hasattr(data, "numpy") else data)
        if d.shape[:2] != a.shape[:2]:
            raise RenderError(f"{path}: layer {name!r} has shape {d.shape}, the colour {a.shape}")
        spec = AOVS.get(name)
        if spec is not None and spec.uint:  # ids: UINT channels of id + 1, 0 for none
            channels[spec.exr[0]] = (d.astype(np.int64) + 1).clip(0, 0xFFFFFFFF).astype(np.uint32)
        elif spec is not None:
            for k, channel in enumerate(spec.exr):
                channels[channel] = d if d.ndim == 2 else d[:, :, k]
        elif d.ndim == 2:  # a layer of the caller's own
            channels[f"{name}.V"] = d
        else:
            for k in range(d.shape[2]):
                channels[f"{name}.{'XYZW'[k]}"] = d[:, :, k]
    write_exr(path, channels, metadata)


def save_image_or_fallback(image, path: str | os.PathLike, metadata: Mapping[str, object] | None = None,
                           folder: str | None = None) -> None:
    """:func:`save_image`; when the write fails on a full disk, quota or I/O error, write the
    image to ``folder`` (default: the system's temporary folder) under a fresh name instead and
    raise the :class:`WriteError` with ``fallback`` set and the message saying where it went."""
    try:
        save_image(image, path, metadata)
    except WriteError as e:
        folder = folder or tempfile.gettempdir()
        stem, ext = os.path.splitext(os.path.basename(os.fspath(path)))
        try:
            fd, fallback = tempfile.mkstemp(prefix=f"{stem}.", suffix=ext, dir=folder)
            os.close(fd)
            try:
                save_image(image, fallback, metadata)
            except BaseException:
                os.unlink(fallback)
                raise
        except (OSError, RenderError) as f:
            raise WriteError(f"{e}; the image could not be written to {folder} either "
                             f"({f.strerror if isinstance(f, OSError) and f.strerror else f})", e.path, e.free) from None
        raise WriteError(f"{e}; the image was written to {fallback} instead", e.path, e.free, fallback) from None


def write_exr(path: str, layers: Mapping[str, np.ndarray], metadata: Mapping[str, object] | None = None) -> None:
    """Write named channels/layers to one EXR file (``RGB`` is the colour): float32, or UINT for
    uint32 arrays."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        if isinstance(v, bool):
            v = int(v)
        if not isinstance(v, (int, float, str)):
            v = str(v)
        header[str(k)] = v
    channels = {name: np.ascontiguousarray(data if np.asarray(data).dtype == np.uint32 else
                                           np.asarray(data, dtype=np.float32)) for name, data in layers.items()}

    def write(p):
        with OpenEXR.File(header, channels) as f:
            f.write(p)

    with Deferred(abandon_on=2, deliver=True):  # (as save_image: a Ctrl-C waits for the file)
        _atomic_write(path, write)


def read_exr(path: str | os.PathLike, layers: bool = False):
    """Read an EXR written by warprt: the RGB image (H, W, 3) float32 and the header; with
    ``layers=True`` also a dict of the other layers (``{"depth": (H, W), "normal": (H, W, 3)...}``,
    the same names, shapes and dtypes as ``render(..., aovs=...)`` returns)."""
    import OpenEXR

    path = _check_path(path, "an EXR file path")
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as e:
        raise RenderError(f"{path}: cannot be read ({e.strerror or e})") from None
    if magic != EXR_MAGIC:  # (checked here: OpenEXR would print its own error line as well)
        raise RenderError(f"{path}: not an OpenEXR file")
    try:
        with OpenEXR.File(path, separate_channels=True) as f:
            header = dict(f.header())
            ch = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except RuntimeError as e:
        raise RenderError(f"{path}: cannot be read as an OpenEXR image ({e})") from None
    if not all(c in ch for c in "RGB"):
        raise RenderError(f"{path}: holds no R, G, B channels (channels: {', '.join(sorted(ch))})")
    rgb = np.stack([ch[c].astype(np.float32) for c in "RGB"], axis=-1)
    if not layers:
        return rgb, header
    from .aov import AOVS

    out = {}
    for name, spec in AOVS.items():  # warprt's AOVs, under their standard channel names
        if all(c in ch for c in spec.exr):
            if spec.uint:
                out[name] = (ch[spec.exr[0]].astype(np.int64) - 1).astype(np.int32)
            elif len(spec.exr) == 1:
                out[name] = ch[spec.exr[0]]
            else:
                out[name] = np.stack([ch[c] for c in spec.exr], axis=-1)
            for c in spec.exr:
                del ch[c]
    grouped: dict[str, dict[str, np.ndarray]] = {}
    for name, data in ch.items():
        if "." in name:
            layer, comp = name.rsplit(".", 1)
            grouped.setdefault(layer, {})[comp] = data
    for layer, comps in grouped.items():
        if set(comps) == {"V"}:
            out[layer] = comps["V"]
        else:
            out[layer] = np.stack([comps[c] for c in "XYZW" if c in comps], axis=-1)
    return rgb, header, out
