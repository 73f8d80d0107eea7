"""Memory a render needs, estimated before anything is built or compiled, against what is free.

Per pixel (bytes): the film's accumulators (Σ radiance vec3 12, Σ luminance² 4, ray and overflow
counts 4 + 4: ``FILM_BYTES`` = 24, on the render device), the float32 image on the host (12),
each AOV (4 per channel, on the device, on the host and in the EXR write: 12 per channel), a PNG
or JPEG (the 8-bit image 3, Pillow's copy 4: 7; 16 bits: the image, its big-endian copy, the
filtered rows and the compressed data, 6 each: 24; the sRGB conversion runs in row chunks, see
:func:`warprt.image.encode_display`) and an EXR (the contiguous RGB copy and the library's
buffer: 24). The check compares the sum with ``MemAvailable`` (Linux ``/proc/meminfo``, read at most once
a second) and is skipped where that is unknown.
"""

from __future__ import annotations

import time

from .aov import AOVS
from .errors import RenderError

FILM_BYTES = 24
IMAGE_BYTES = 12
PNG_BYTES = 7
PNG16_BYTES = 24
EXR_BYTES = 24
AOV_CHANNEL_BYTES = 12


def estimate_bytes(width: int, height: int, aovs=(), formats=(".png",), film_on_host: bool = True,
                   bits: int | None = None) -> int:
    """Host memory (bytes) a ``width`` × ``height`` render with ``aovs`` written to ``formats``
    (extensions; ``bits`` 16 for a 16-bit PNG) needs at its peak; ``film_on_host=False`` when
    the film lives on a GPU."""
    per_pixel = IMAGE_BYTES + (FILM_BYTES if film_on_host else 0)
    formats = {f.lower() for f in formats}
    if formats & {".png", ".jpg", ".jpeg"}:
        per_pixel += PNG16_BYTES if bits == 16 and ".png" in formats else PNG_BYTES
    if ".exr" in formats:
        per_pixel += EXR_BYTES
    per_pixel += sum(AOV_CHANNEL_BYTES * (AOVS[a].channels if a in AOVS else 3) for a in (aovs or ()))
    return int(width) * int(height) * per_pixel


AVAILABLE_TTL_S = 1.0  # a MemAvailable reading serves the checks of the next second
_available: tuple[float, int | None] | None = None  # (monotonic time read, value)


def available_bytes() -> int | None:
    """``MemAvailable`` from /proc/meminfo, or None where unknown (not Linux); read at most once
    per AVAILABLE_TTL_S (the file costs ~0.2 ms to read, which a loop of small renders, each
    checked, would pay every frame)."""
    global _available
    now = time.monotonic()
    if _available is not None and now - _available[0] < AVAILABLE_TTL_S:
        return _available[1]
    value = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    value = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    _available = (now, value)
    return value


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.1f} MB"


def check_memory(width: int, height: int, aovs=(), formats=(".png",), film_on_host: bool = True,
                 bits: int | None = None) -> int:
    """Refuse (:class:`RenderError`, one line with the estimate and what is available) a render
    whose estimate exceeds the available memory; returns the estimate."""
    need = estimate_bytes(width, height, aovs, formats, film_on_host, bits)
    have = available_bytes()
    if have is not None and need > have:
        raise RenderError(f"a {width}x{height} render needs about {_gb(need)} of memory (film, image"
                          f"{', AOVs' if aovs else ''} and output), but only {_gb(have)} is available; "
                          "lower the width/height")
    return need
