"""The memory estimate made before a render (warprt.memory) and the chunked sRGB conversion."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

import warprt
import warprt.memory
from warprt.cli import main
from warprt.film import Film
from warprt.image import linear_to_srgb8
from warprt.memory import FILM_BYTES, IMAGE_BYTES, estimate_bytes


def test_the_estimate_counts_the_film_and_image_buffers_as_allocated():
    film = Film(7, 5, wp.get_device("cpu"))
    d = film.data
    measured = sum(a.capacity for a in (d.accum, d.accum_sq, d.rays, d.overflow))
    assert measured == FILM_BYTES * 35
    assert film.image(1).nbytes == IMAGE_BYTES * 35
    assert estimate_bytes(7, 5, formats=()) == measured + film.image(1).nbytes
    # PNG + EXR, no AOVs: 67 B per pixel (73 measured before the chunked sRGB conversion)
    assert estimate_bytes(32768, 32768, formats=(".png", ".exr")) == 67 * 32768 ** 2
    assert estimate_bytes(10, 10, aovs=["depth", "normal"], formats=()) == 100 * (36 + 12 * 4)
    assert estimate_bytes(10, 10, formats=(), film_on_host=False) == 100 * IMAGE_BYTES


@pytest.fixture
def little_memory(monkeypatch):
    monkeypatch.setattr(warprt.memory, "available_bytes", lambda: 10_000)

    def never(*a, **k):
        raise AssertionError("compiled or rendered although the memory check should refuse")

    monkeypatch.setattr(warprt.Renderer, "compile", never)


def test_a_render_larger_than_the_available_memory_is_refused_before_compiling(little_memory, device):
    # host memory: the film's sums as well on the CPU (36 bytes a pixel), the image alone with the
    # film on a GPU (12 bytes): 200 x 100 x 36 = 0.72 MB, 200 x 100 x 12 = 0.24 MB
    need = "0.7" if device == "cpu" else "0.2"
    scene = warprt.scene_from_string("[camera]\nwidth = 200\nheight = 100\n")
    with pytest.raises(warprt.RenderError, match=rf"200x100 render needs about {need} MB .* only 0\.0 MB is available"):
        warprt.Renderer(scene, device=device).render(spp=1, progress=False)


def test_the_cli_refuses_in_one_line_and_writes_nothing(little_memory, tmp_path, capsys):
    (tmp_path / "s.toml").write_text("[camera]\nwidth = 200\nheight = 100\n")
    code = main(["render", str(tmp_path / "s.toml"), "-o", str(tmp_path / "o.png"), "-o", str(tmp_path / "o.exr"),
                 "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "needs about" in err[0] and "available" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def _old_srgb8(image):
    x = np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.clip(np.round(s * 255.0), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("rows", [None, 1, 3, 7, 100])
def test_chunked_srgb_conversion_gives_the_same_bytes(rows):
    rng = np.random.default_rng(3)
    image = rng.uniform(-0.2, 1.5, size=(17, 11, 3)).astype(np.float32)
    image[0, 0] = [np.nan, np.inf, -np.inf]
    image[5, 3] = [0.0031308, 0.0031307, 1.0]
    assert linear_to_srgb8(image, chunk_rows=rows).tobytes() == _old_srgb8(image).tobytes()


def test_available_memory_is_read_at_most_once_a_second(monkeypatch):
    """``available_bytes`` keeps a /proc/meminfo reading for AVAILABLE_TTL_S (a loop of small
    renders checks every frame), then reads the file again."""
    import io
    from types import SimpleNamespace

    clock = [100.0]
    text = ["MemTotal: 9000 kB\nMemAvailable: 1000 kB\n"]
    reads = []

    def fake_open(path, *a, **k):
        reads.append(path)
        return io.StringIO(text[0])

    monkeypatch.setattr(warprt.memory, "open", fake_open, raising=False)
    monkeypatch.setattr(warprt.memory, "time", SimpleNamespace(monotonic=lambda: clock[0]))
    monkeypatch.setattr(warprt.memory, "_available", None)
    assert warprt.memory.available_bytes() == 1000 * 1024 and reads == ["/proc/meminfo"]
    text[0] = "MemAvailable: 2000 kB\n"
    clock[0] += 0.9 * warprt.memory.AVAILABLE_TTL_S
    assert warprt.memory.available_bytes() == 1000 * 1024 and len(reads) == 1
    clock[0] += 0.2 * warprt.memory.AVAILABLE_TTL_S
    assert warprt.memory.available_bytes() == 2000 * 1024 and len(reads) == 2
    # where the file is unreadable: unknown, and that answer is kept as long
    monkeypatch.setattr(warprt.memory, "open", lambda *a, **k: (_ for _ in ()).throw(OSError("no /proc")),
                        raising=False)
    clock[0] += 2.0 * warprt.memory.AVAILABLE_TTL_S
    assert warprt.memory.available_bytes() is None
