"""Writing images: linear EXR (float32 or half), sRGB PNG (8 or 16 bits) and JPEG, always atomically.

:func:`save_image` takes an image array, a result (:class:`warprt.RenderResult`, a batch's
``frame()``, the dict of AOVs ``warprt.render(..., aovs=[...])`` returns) or a plain dict of
layers, and writes the metadata it has (:mod:`warprt.results`) with the ``metadata`` given.

* ``.exr``: linear radiance through OpenEXR (ZIP compression), float32, or half float with
  ``bits=16`` (colour, alpha, normals, albedo and motion; distances and positions stay float32,
  ids UINT). With the coverage AOV the colour is **premultiplied RGBA**: ``A`` is the coverage
  (the fraction of the pixel's samples that hit a surface) and ``RGB`` the light of those samples
  alone (the render's colour less (1 − A) × the background), so a compositor's "over" adds its
  own plate once. The AOVs take the names compositors read (``aov.EXR_CHANNELS``: ``Z``
  camera-space depth, ``N.X``..., ``P.X``..., ``forward.u``/``forward.v`` motion, ids as UINT
  id + 1 with their name tables in the header); the header holds the camera's standard
  ``worldToCamera`` and ``worldToNDC`` matrices and ``warprt_exr_layout`` = 2.
  :func:`read_exr` reads this layout and warprt's earlier one (without the layout attribute:
  ``Z`` the distance along the ray, ``z.V``, ``motion.X``/``motion.Y``, RGB not premultiplied).
* ``.png``: the sRGB view (:func:`warprt.colour.view`: ``exposure`` in stops, then the sRGB
  curve on values clipped to [0, 1]), rounded to 8 bits (Pillow) or, with ``bits=16``, to 16
  bits (a 48-bit RGB PNG, which Pillow cannot write: :func:`_png16`); ``metadata`` goes into
  text chunks, as strings (arrays as JSON lists). NaN becomes 0.
* ``.jpg`` / ``.jpeg``: the same 8-bit view through Pillow (quality 95, no chroma subsampling);
  ``metadata`` goes into the comment as a JSON object.

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
import json
import os
import re
import stat
import tempfile
from typing import Mapping

import numpy as np

from .errors import RenderError, WriteError
from .signals import Deferred

FORMATS = (".exr", ".png", ".jpg", ".jpeg")
FORMATS_TEXT = ".exr, .png or .jpg"
# bits per channel each format writes (the first is its default): EXR 32 (float) or 16 (half)
BITS = {".exr": (32, 16), ".png": (8, 16), ".jpg": (8,), ".jpeg": (8,)}
EXR_MAGIC = b"\x76\x2f\x31\x01"  # the first four bytes of every OpenEXR file
EXR_LAYOUT = 2  # warprt_exr_layout of the files written here (absent: the earlier layout)
# the earlier layout's channels where they differ (read_exr reads both)
LEGACY_EXR = {"depth": ("Z",), "z": ("z.V",), "motion": ("motion.X", "motion.Y")}
HALF_MAX = 65504.0  # the largest finite half float
JPEG_QUALITY = 95


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise RenderError(f"an image must have shape (H, W, 3), (H, W, 4) or (H, W), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise RenderError(f"an image must hold numbers, got dtype {a.dtype}")
    return a.astype(np.float32, copy=False)


SRGB_CHUNK_PIXELS = 1 << 20  # pixels converted at a time: the float temporaries stay a few MB


def encode_display(image: np.ndarray, bits: int = 8, exposure: float = 0.0, chunk_rows: int | None = None) -> np.ndarray:
    """Linear float to the sRGB view (:func:`warprt.colour.view`) rounded to ``bits`` (8: uint8,
    16: uint16), in chunks of rows, so the float temporaries never span the whole image (the
    output is the only full-size allocation); elementwise, so the values do not depend on the
    chunking."""
    from .colour import quantize, view

    image = np.asarray(image)
    dtype = np.float32 if bits == 8 else np.float64
    if image.ndim < 2 or image.shape[0] == 0:
        return quantize(view(image, exposure, dtype), bits)
    row = max(1, int(np.prod(image.shape[1:-1] if image.ndim > 2 else image.shape[1:])))
    rows = chunk_rows or max(1, SRGB_CHUNK_PIXELS // row)
    out = np.empty(image.shape, dtype=np.uint8 if bits == 8 else np.uint16)
    for r0 in range(0, image.shape[0], rows):
        out[r0:r0 + rows] = quantize(view(image[r0:r0 + rows], exposure, dtype), bits)
    return out


def linear_to_srgb8(image: np.ndarray, chunk_rows: int | None = None) -> np.ndarray:
    """Linear float to 8-bit sRGB (:func:`encode_display` at exposure 0)."""
    return encode_display(image, 8, 0.0, chunk_rows)


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
        raise RenderError(f"{path}: unsupported image format {ext or '(none)'!r}; use {FORMATS_TEXT}")
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
        elif ext in (".jpg", ".jpeg"):
            from PIL import Image, JpegImagePlugin  # noqa: F401
    except ImportError as e:
        package = "OpenEXR" if ext == ".exr" else "Pillow"
        raise RenderError(f"{path or ext}: writing {ext} files needs {package} ({e}); "
                          f"pip install {package}") from None


# bytes per pixel of a file at most (no compression): the EXR's float32 RGB and each AOV channel
# (4 bytes, float32 or uint32; half floats take less), the PNG's 8-bit RGB (16-bit: 6), a JPEG's
# (at quality 95 well under its 3 bytes of RGB); plus headers and the compressors' worst case
EXR_PIXEL_BYTES = 12
EXR_CHANNEL_BYTES = 4
PNG_PIXEL_BYTES = 3
FILE_OVERHEAD = 64 * 1024  # header, offset tables
INCOMPRESSIBLE = 1.01  # zlib's worst case adds a fraction of a percent to incompressible data


def estimate_file_bytes(path: str, width: int, height: int, aov_channels: int = 0, bits: int | None = None) -> int:
    """The largest size a ``width`` × ``height`` image written to ``path`` can take (an EXR with
    ``aov_channels`` extra channels, and the alpha; a PNG or JPEG holds the colour only)."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext == ".exr":
        per_pixel = EXR_PIXEL_BYTES + EXR_CHANNEL_BYTES * aov_channels
    else:
        per_pixel = PNG_PIXEL_BYTES * (2 if bits == 16 else 1)
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


def save_image(image, path: str | os.PathLike, metadata: Mapping[str, object] | None = None, *,
               exposure: float = 0.0, bits: int | None = None) -> None:
    """Write ``image`` to ``path``; the format follows the extension (``.exr``, ``.png``, ``.jpg``).

    ``image`` is a linear float image ((H, W, 3), (H, W) grey or (H, W, 4) RGBA taken as
    premultiplied; numpy or ``wp.array``), a result (:class:`warprt.RenderResult`,
    ``BatchResult.frame(w, c)``, a batch of one image, the dict ``render(..., aovs=[...])``
    returns), whose AOVs and metadata come with it, or a plain dict of layers ``{"color": rgb,
    "depth": ..., "mine": ...}``. An EXR holds every layer: warprt's AOVs under the channel names
    of ``aov.EXR_CHANNELS`` (with the coverage AOV the colour is premultiplied RGBA, see the
    module docstring; a plain dict has no background to take out, so its colour is written as
    it is), other layers as ``layer.X`` / ``layer.Y`` / ... (``layer.V`` for one channel); a PNG
    or JPEG holds the colour.

    ``metadata``: header attributes (EXR), text chunks (PNG) or comment entries (JPEG), added to
    the result's own (and overriding them). ``exposure`` (stops): PNG and JPEG show the image
    times 2^exposure (an EXR keeps the radiance). ``bits=16``: a half-float EXR or a 16-bit PNG
    (default: float32 EXR, 8-bit PNG and JPEG).

    A Ctrl-C during the write is held until the file is complete (then raised); a second one
    abandons it. A full disk, quota or I/O error raises :class:`warprt.errors.WriteError`.
    """
    with Deferred(abandon_on=2, deliver=True):
        _save_image(image, path, metadata, exposure, bits)


def _check_path(path, what: str = "an image path") -> str:
    if not isinstance(path, (str, os.PathLike)):
        raise RenderError(f"expected {what} (str or os.PathLike), got {type(path).__name__}")
    return os.fspath(path)


def check_bits(ext: str, bits, path: str = "") -> int:
    """The bits per channel of a ``ext`` file (None: the format's default), else a RenderError."""
    allowed = BITS[ext]
    if bits is None:
        return allowed[0]
    if isinstance(bits, bool) or bits not in allowed:
        raise RenderError(f"{path or ext}: bits must be {' or '.join(map(str, sorted(allowed)))} for {ext} files "
                          f"(16: {'half float' if ext == '.exr' else 'a 16-bit PNG'}), got {bits!r:.60}"
                          if len(allowed) > 1 else f"{path or ext}: {ext} files are 8 bits per channel, got bits={bits!r:.60}")
    return int(bits)


def _host(x) -> np.ndarray:
    """An array on the host (a ``wp.array`` copied from its device)."""
    return np.asarray(x.numpy() if hasattr(x, "numpy") and not isinstance(x, np.ndarray) else x)


def _unpack(image, path: str) -> tuple[object, dict | None, dict]:
    """(colour, layers or None, metadata) of what ``save_image`` was given."""
    if callable(getattr(image, "frame", None)) and hasattr(image, "color"):  # a BatchResult
        worlds, cameras = image.color.shape[:2]
        if worlds * cameras != 1:
            raise RenderError(f"{path}: a batch holds {worlds} worlds x {cameras} cameras of images; save one "
                              f"with save_image(result.frame(world, camera), path)")
        image = image.frame(0, 0)
    if all(hasattr(image, a) for a in ("image", "aovs", "metadata")):  # a result (RenderLayers too)
        return image.image, dict(image.aovs), dict(image.metadata)
    if isinstance(image, Mapping):
        if "color" not in image:
            raise RenderError(f"{path}: a dict of layers needs a 'color' entry, got {sorted(image)}")
        return image["color"], {k: v for k, v in image.items() if k != "color"}, {}
    return image, None, {}


def _text(value) -> str:
    """A metadata value as PNG/JPEG text: booleans as 0/1, arrays as JSON lists."""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, np.ndarray):
        return json.dumps(value.tolist())
    if isinstance(value, (np.integer, np.floating)):
        return str(value.item())
    return str(value)


def _save_image(image, path, metadata, exposure=0.0, bits=None) -> None:
    from .colour import check_exposure

    path = _check_path(path)
    if metadata is not None and not isinstance(metadata, Mapping):
        raise RenderError(f"{path}: metadata must be a dict of name: value, got {type(metadata).__name__}")
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise RenderError(f"{path}: unsupported image format {ext or '(none)'!r}; use {FORMATS_TEXT}")
    bits = check_bits(ext, bits, path)
    exposure = check_exposure(exposure)
    colour, layers, meta = _unpack(image, path)
    meta.update(metadata or {})
    a = _check_image(_host(colour))
    if ext != ".exr":
        from PIL import Image

        pixels = encode_display(a[:, :, :3], bits, exposure)
        text = {str(k): _text(v) for k, v in meta.items()}
        if exposure:
            text.setdefault("warprt_exposure", _text(exposure))
        if ext == ".png" and bits == 16:
            _atomic_write(path, lambda p: _png16(p, pixels, text))
        elif ext == ".png":
            from PIL.PngImagePlugin import PngInfo

            info = PngInfo()
            for k, v in text.items():  # tEXt chunks, e.g. warprt:partial = true
                info.add_text(k, v)
            _atomic_write(path, lambda p: Image.fromarray(pixels, mode="RGB").save(p, format="PNG", pnginfo=info))
        else:  # JPEG: the metadata as a JSON object in the comment
            comment = json.dumps(text).encode("utf-8") if text else b""
            _atomic_write(path, lambda p: Image.fromarray(pixels, mode="RGB").save(
                p, format="JPEG", quality=JPEG_QUALITY, subsampling=0, comment=comment))
        return
    channels = exr_channels(path, a, layers, meta.get("warprt_background"), half=bits == 16)
    write_exr(path, channels, {**meta, "warprt_exr_layout": EXR_LAYOUT})


def premultiply(rgb: np.ndarray, coverage: np.ndarray, background) -> np.ndarray:
    """The colour of a render (background included where samples missed) as premultiplied RGB
    over alpha = ``coverage``: the light of the samples that hit alone, colour − (1 − coverage) ×
    background (never below 0; exactly 0 where nothing was hit). A camera ray that misses adds
    exactly the background (``integrator``), so this is the hits' mean light times their
    fraction, to float32 rounding; with a black background the colour itself, bit for bit."""
    bg = np.asarray(background, np.float64).reshape(-1)[:3]
    cov = np.asarray(coverage, np.float64)[..., None]
    light = np.maximum(np.asarray(rgb, np.float64) - (1.0 - cov) * bg, 0.0)
    return np.where(cov > 0.0, light, 0.0).astype(np.float32)


def _half(x) -> np.ndarray:
    """Float32 values as half floats, finite values beyond half's range clipped to ±65504."""
    return np.clip(np.asarray(x, np.float32), -HALF_MAX, HALF_MAX).astype(np.float16)


def exr_channels(path: str, a: np.ndarray, layers: Mapping | None, background=None, half: bool = False) -> dict:
    """The EXR channels of colour ``a`` (H, W, 3 or 4) and ``layers`` (see :func:`save_image`):
    R, G, B, A (the coverage AOV's, or an RGBA image's fourth channel), then the layers."""
    from .aov import AOVS

    shape = a.shape[:2]
    arrays = {}
    for name, data in (layers or {}).items():
        d = _host(data)
        if d.shape[:2] != shape:
            raise RenderError(f"{path}: layer {name!r} has shape {d.shape}, the colour {a.shape}")
        arrays[name] = d
    rgb, alpha = a[:, :, :3], None
    if "coverage" in arrays:
        alpha = np.asarray(arrays.pop("coverage"), np.float32).reshape(shape)
        if background is not None:
            rgb = premultiply(rgb, alpha, background)
    elif a.shape[2] == 4:
        alpha = a[:, :, 3]
    colour = _half if half else (lambda x: np.asarray(x, np.float32))
    channels = {c: colour(rgb[:, :, k]) for k, c in enumerate("RGB")}
    if alpha is not None:
        channels["A"] = colour(alpha)
    for name, d in arrays.items():
        spec = AOVS.get(name)
        if spec is not None and spec.uint:  # ids: UINT channels of id + 1, 0 for none
            channels[spec.exr[0]] = (d.astype(np.int64) + 1).clip(0, 0xFFFFFFFF).astype(np.uint32)
        elif spec is not None:
            store = _half if half and spec.half else (lambda x: np.asarray(x, np.float32))
            for k, channel in enumerate(spec.exr):
                c = d if d.ndim == 2 else d[:, :, k]
                sign = spec.signs[k] if spec.signs else 1.0
                channels[channel] = store(c if sign == 1.0 else sign * np.asarray(c, np.float32))
        elif d.ndim == 2:  # a layer of the caller's own
            channels[f"{name}.V"] = colour(d) if np.issubdtype(d.dtype, np.floating) else d
        else:
            for k in range(d.shape[2]):
                channels[f"{name}.{'XYZW'[k]}"] = colour(d[:, :, k]) if np.issubdtype(d.dtype, np.floating) \
                    else d[:, :, k]
    return channels


def _png16(path: str, rgb16: np.ndarray, text: Mapping[str, str]) -> None:
    """Write a 48-bit RGB PNG (bit depth 16, colour type 2; the PNG specification, 11.2), which
    Pillow cannot: big-endian samples, each row with filter type 2 ("Up": the byte-wise
    difference from the row above), deflated by zlib; ``text`` as tEXt chunks (iTXt, UTF-8,
    for text that is not Latin-1)."""
    import struct
    import zlib

    h, w, _ = rgb16.shape

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    raw = np.ascontiguousarray(rgb16, dtype=">u2").view(np.uint8).reshape(h, 6 * w)
    rows = np.empty((h, 6 * w + 1), np.uint8)
    rows[:, 0] = 2  # Up
    rows[:, 1:] = raw
    rows[1:, 1:] -= raw[:-1]  # (uint8: modulo 256, as the filter is defined)
    parts = [b"\x89PNG\r\n\x1a\n", chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))]
    for key, value in text.items():
        k = key.encode("latin-1", "replace")[:79]
        try:
            parts.append(chunk(b"tEXt", k + b"\0" + value.encode("latin-1")))
        except UnicodeEncodeError:
            parts.append(chunk(b"iTXt", k + b"\0\0\0\0\0" + value.encode("utf-8")))
    parts.append(chunk(b"IDAT", zlib.compress(rows, 6)))
    parts.append(chunk(b"IEND", b""))
    with open(path, "wb") as f:
        for part in parts:
            f.write(part)


def save_image_or_fallback(image, path: str | os.PathLike, metadata: Mapping[str, object] | None = None,
                           folder: str | None = None, **options) -> None:
    """:func:`save_image` (``options``: its ``exposure`` and ``bits``); when the write fails on a
    full disk, quota or I/O error, write the image to ``folder`` (default: the system's
    temporary folder) under a fresh name instead and raise the :class:`WriteError` with
    ``fallback`` set and the message saying where it went."""
    try:
        save_image(image, path, metadata, **options)
    except WriteError as e:
        folder = folder or tempfile.gettempdir()
        stem, ext = os.path.splitext(os.path.basename(os.fspath(path)))
        try:
            fd, fallback = tempfile.mkstemp(prefix=f"{stem}.", suffix=ext, dir=folder)
            os.close(fd)
            try:
                save_image(image, fallback, metadata, **options)
            except BaseException:
                os.unlink(fallback)
                raise
        except (OSError, RenderError) as f:
            raise WriteError(f"{e}; the image could not be written to {folder} either "
                             f"({f.strerror if isinstance(f, OSError) and f.strerror else f})", e.path, e.free) from None
        raise WriteError(f"{e}; the image was written to {fallback} instead", e.path, e.free, fallback) from None


def _header_value(v):
    """A metadata value as an EXR attribute: int, float or str; a numeric 4×4 or 3×3 array as a
    float32 matrix (M44f, M33f), a 2- or 3-vector as V2f/V3f; anything else as its string."""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    if isinstance(v, np.ndarray) and v.dtype.kind in "fiu" and v.shape in ((4, 4), (3, 3), (3,), (2,)):
        return np.ascontiguousarray(v, dtype=np.float32)
    if not isinstance(v, (int, float, str)):
        return str(v)
    return v


def write_exr(path: str, layers: Mapping[str, np.ndarray], metadata: Mapping[str, object] | None = None) -> None:
    """Write named channels/layers to one EXR file (``RGB`` is the colour): float32, HALF for
    float16 arrays, UINT for uint32 arrays; ``metadata`` as header attributes (``_header_value``)."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        header[str(k)] = _header_value(v)
    channels = {name: np.ascontiguousarray(data if np.asarray(data).dtype in (np.uint32, np.float16) else
                                           np.asarray(data, dtype=np.float32)) for name, data in layers.items()}

    def write(p):
        with OpenEXR.File(header, channels) as f:
            f.write(p)

    with Deferred(abandon_on=2, deliver=True):  # (as save_image: a Ctrl-C waits for the file)
        _atomic_write(path, write)


def read_exr(path: str | os.PathLike, layers: bool = False):
    """Read an EXR written by warprt (this layout or the earlier one, see the module docstring;
    any EXR with R, G and B channels): the colour as the render returned it, (H, W, 3) float32
    (a premultiplied file's background, ``warprt_background``, added back where the coverage is
    below 1: bit for bit where the coverage is 1, and everywhere under a black background; to
    float32 rounding elsewhere), and the header; with ``layers=True`` also a dict of the other layers
    (``{"depth": (H, W), "normal": (H, W, 3)...}``, the same names, shapes and dtypes as
    ``render(..., aovs=...)`` returns; ``coverage`` is the alpha)."""
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
    layout = header.get("warprt_exr_layout", 0)
    current = isinstance(layout, int) and layout >= EXR_LAYOUT
    rgb = np.stack([ch[c].astype(np.float32) for c in "RGB"], axis=-1)
    background = header.get("warprt_background")
    if current and "A" in ch and background is not None:  # the render's colour: the background back in
        cov = ch["A"].astype(np.float64)[..., None]
        rgb = (rgb.astype(np.float64) + (1.0 - cov) * np.asarray(background, np.float64).reshape(-1)[:3]) \
            .astype(np.float32)
    if not layers:
        return rgb, header
    from .aov import AOVS

    out = {}
    for name, spec in AOVS.items():  # warprt's AOVs, under their channel names of the file's layout
        names = spec.exr if current else LEGACY_EXR.get(name, spec.exr)
        signs = spec.signs if current and spec.signs else (1.0,) * len(names)
        if all(c in ch for c in names):
            if spec.uint:
                out[name] = (ch[names[0]].astype(np.int64) - 1).astype(np.int32)
            else:
                parts = [ch[c].astype(np.float32) * np.float32(s) if s != 1.0 else ch[c].astype(np.float32)
                         for c, s in zip(names, signs)]
                out[name] = parts[0] if len(parts) == 1 else np.stack(parts, axis=-1)
            for c in names:
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
