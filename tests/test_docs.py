"""The documentation's code runs as written.

Every fenced ```python block of README.md and docs/**/*.md is run, in the order it appears, in one
fresh Python process per markdown file: a reader pastes the blocks of a page one after another
into one session, so a later block may use names an earlier one defined, but nothing else is
given to it. The process starts in a temporary folder holding what a fresh clone has and the
blocks may read (``scenes/``, ``examples/``) and nothing a previous run made (no ``out/``), with
this repository first on ``sys.path``. A block that writes into a folder must
create it, as a reader's first run would have to.

A block that is a fragment on purpose (a pattern with placeholders, or one that needs a Ray
cluster) has ``<!-- fragment: why -->`` on the line before its fence. It is not run, but it must
still compile, so a typo in it fails here too. Fragments are few: a page that is all fragments
would check nothing.

``sh`` blocks are not run (they install, compile and render at full size); their ``warprt``
command lines are parsed by the CLI's own argument parser and the scene files they name must exist
in the repository, so a renamed flag or a missing scene fails here. A ``toml`` block that opens
with ``# from scenes/NAME.toml`` must be an excerpt of that file, and the tests the docs name
(``tests/test_x.py::test_name``) must exist.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from warprt.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

# What of a fresh clone the blocks may read, copied into the working folder of each run.
CLONE_PARTS = ("scenes", "examples")

# One page's blocks render a handful of small images (at most about a million samples in all)
# after loading their kernels; warm, the slowest page (README.md) takes about 4 s on 2 cores. On
# a cold kernel cache each new feature set costs a compile of 3-7 s (README.md: kernel cache),
# and a page uses up to four, so 300 s leaves room for a loaded machine without hiding a hang.
PAGE_TIMEOUT_S = 300

FRAGMENT = re.compile(r"<!--\s*fragment:\s*\S.*-->")
FENCE = re.compile(r"^(`{3,})\s*([\w+-]*)")


@dataclass(frozen=True)
class Block:
    page: str  # path relative to the repository root
    line: int  # 1-based line of the first code line (the one after the opening fence)
    lang: str
    code: str
    fragment: bool


def blocks_of(page: Path) -> list[Block]:
    """The fenced code blocks of a markdown page, in order. A fence opens with three or more
    backticks at the start of a line and closes with at least as many; the language is the word
    after the opening fence ('' when none)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    rel = page.relative_to(ROOT).as_posix()
    blocks, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        ticks, lang = m.group(1), m.group(2).lower()
        fragment = i > 0 and FRAGMENT.search(lines[i - 1]) is not None
        j = i + 1
        while j < len(lines) and not (lines[j].startswith(ticks) and lines[j].strip() == "`" * len(lines[j].strip())):
            j += 1
        assert j < len(lines), f"{rel}:{i + 1}: code fence never closed"
        blocks.append(Block(rel, i + 2, lang, "\n".join(lines[i + 1:j]) + "\n", fragment))
        i = j + 1
    return blocks


def python_blocks(page: Path) -> list[Block]:
    return [b for b in blocks_of(page) if b.lang in ("python", "py", "python3")]


PAGES_WITH_PYTHON = [p for p in DOCS if any(not b.fragment for b in python_blocks(p))]


def compile_block(block: Block):
    """Compile a block so that errors name the markdown page and its own line numbers."""
    return compile("\n" * (block.line - 1) + block.code, block.page, "exec")


# Runs in the fresh process: each block is compiled under the page's name with blank lines in
# front, so a traceback reads `File "docs/pipelines.md", line 17`, and executed in one shared
# __main__ namespace, as pasted into one interpreter.
RUNNER = textwrap.dedent("""
    import json, sys, time, __main__
    blocks = json.load(open(sys.argv[1], encoding="utf-8"))
    for page, line, code in blocks:
        print(f"--- {page}:{line}", flush=True)
        start = time.perf_counter()
        exec(compile("\\n" * (line - 1) + code, page, "exec"), __main__.__dict__)
        print(f"--- {page}:{line} ran in {time.perf_counter() - start:.2f} s", flush=True)
    print("--- all blocks ran", flush=True)
""")


def fresh_clone_folder(tmp_path: Path) -> Path:
    """A working folder with the parts of the repository a reader's clone has and the blocks
    read; no out/ or other output of earlier runs."""
    work = tmp_path / "clone"
    for part in CLONE_PARTS:
        shutil.copytree(ROOT / part, work / part)
    return work


def run_page(page: Path, work: Path) -> subprocess.CompletedProcess:
    blocks = [b for b in python_blocks(page) if not b.fragment]
    spec = work.parent / "blocks.json"
    spec.write_text(json.dumps([(b.page, b.line, b.code) for b in blocks]), encoding="utf-8")
    env = dict(os.environ)  # WARP_CACHE_PATH (set by conftest.py) is inherited: kernels are shared
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env.pop("WARPRT_DIFF_DIR", None)
    env.pop("WARPRT_UPDATE_REFERENCES", None)
    proc = subprocess.run([sys.executable, "-c", RUNNER, str(spec)], cwd=work, env=env, capture_output=True,
                          text=True, timeout=PAGE_TIMEOUT_S)
    assert proc.returncode == 0, (f"a python block of {page.relative_to(ROOT)} failed "
                                  f"(exit {proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-6000:]}")
    assert proc.stdout.rstrip().endswith("--- all blocks ran")
    return proc


def png_pixels(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


# --- what is found -------------------------------------------------------------------------------


def test_every_python_fence_is_found():
    """The parser sees every python fence, indented ones included (it reads fences at the start of
    a line only, so an indented block would silently not run), and the pages that teach the API
    have blocks that run."""
    for page in DOCS:
        text = page.read_text(encoding="utf-8")
        fences = re.findall(r"^[ \t>]*`{3,}[ \t]*(?:python|py|python3)[ \t]*$", text, flags=re.M)
        assert len(python_blocks(page)) == len(fences), f"{page}: a python block the test cannot read"
    names = {p.relative_to(ROOT).as_posix() for p in PAGES_WITH_PYTHON}
    assert {"README.md", "docs/pipelines.md", "docs/effects/soft-shadows.md"} <= names


def test_fragments_are_few_and_compile():
    """A fragment is not run, so it is at least compiled (a syntax error or a stray indent fails
    here). Fragments are kept to a few; most blocks must run."""
    blocks = [b for page in DOCS for b in python_blocks(page)]
    fragments = [b for b in blocks if b.fragment]
    for b in fragments:
        compile_block(b)
    assert len(fragments) <= 3, [f"{b.page}:{b.line}" for b in fragments]
    assert len(blocks) - len(fragments) >= 15


# --- the blocks run -------------------------------------------------------------------------------


@pytest.mark.parametrize("page", PAGES_WITH_PYTHON, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_python_blocks_run_in_order(page, tmp_path):
    """Each page's runnable blocks, in order, in one fresh interpreter started in a fresh-clone
    folder. What a page writes is checked where that is its point (see below)."""
    work = fresh_clone_folder(tmp_path)
    run_page(page, work)
    rel = page.relative_to(ROOT).as_posix()
    if rel == "README.md":
        # the first block writes the image it talks about, creating out/ itself
        assert png_pixels(work / "out" / "showcase.png").max() > 0
        assert (work / "out" / "showcase.exr").is_file()
    if rel == "docs/pipelines.md":
        check_pipeline_outputs(work)


def check_pipeline_outputs(work: Path) -> None:
    """The AOV block's EXR has its layers, and the keyframe example's frames exist, are lit (not
    black, and the floor brighter than ambient light alone makes it: the scene file has a light)
    and differ (the sphere moves between them)."""
    import warprt

    _, _, layers = warprt.read_exr(work / "out" / "frame.exr", layers=True)
    assert {"depth", "normal", "object_id", "motion"} <= set(layers)
    frames = sorted((work / "out").glob("anim_*.png"))
    assert len(frames) >= 2, frames
    pixels = [png_pixels(f) for f in frames]
    for f, p in zip(frames, pixels):
        assert p.mean() > 20, f"{f.name} is (nearly) black: mean 8-bit value {p.mean():.1f}"
        # The floor in front (the bottom eighth of the frame) is lit by the point light: about
        # 195 in 8-bit sRGB, where the ambient term alone (ka·Ia = 0.7·0.1) would give about 76.
        floor = p[-max(1, p.shape[0] // 8):].mean()
        assert floor > 130, f"{f.name}: the floor is not lit (mean 8-bit value {floor:.1f})"
    assert not np.array_equal(pixels[0], pixels[-1]), "the first and last frames are the same"


# --- shell blocks ------------------------------------------------------------------------------------


def cli_lines(page: Path) -> list[tuple[str, list[str]]]:
    """``warprt ...`` and ``python -m warprt ...`` commands in the page's sh/bash blocks, with
    their arguments after the program name (comments and environment assignments dropped)."""
    found = []
    for b in blocks_of(page):
        if b.lang not in ("sh", "bash", "shell", "console"):
            continue
        for offset, line in enumerate(b.code.splitlines()):
            # a comment starts at a '#' after a blank ('#' inside a word is a frame pattern)
            words = shlex.split(re.sub(r"(^|\s)#.*$", "", line))
            while words and re.fullmatch(r"\w+=.*", words[0]):
                words.pop(0)
            if len(words) >= 3 and words[0].endswith("python") and words[1:3] == ["-m", "warprt"]:
                found.append((f"{b.page}:{b.line + offset}", words[3:]))
            elif words and words[0] == "warprt":
                found.append((f"{b.page}:{b.line + offset}", words[1:]))
    return found


CLI_LINES = [c for page in DOCS for c in cli_lines(page)]


def test_sh_blocks_have_warprt_commands():
    assert len(CLI_LINES) >= 3, CLI_LINES


@pytest.mark.parametrize("where,argv", CLI_LINES, ids=[w for w, _ in CLI_LINES])
def test_cli_lines_parse(where, argv):
    """The documented command lines parse with the CLI's own parser (argparse exits on a bad
    flag), and the scene file they render is in the repository."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        pytest.fail(f"{where}: `warprt {' '.join(argv)}` does not parse (exit {e.code})")
    assert (ROOT / args.scene).is_file(), f"{where}: {args.scene} is not in the repository"


# --- excerpts and references -----------------------------------------------------------------------


def is_excerpt(part, whole) -> bool:
    """``part`` (parsed TOML) is contained in ``whole``: tables key by key, arrays of tables as
    an in-order subsequence of tables each contained in its match, any other value equal."""
    if isinstance(part, dict):
        return isinstance(whole, dict) and all(k in whole and is_excerpt(v, whole[k]) for k, v in part.items())
    if isinstance(part, list) and part and all(isinstance(x, dict) for x in part):
        rest = iter(whole) if isinstance(whole, list) else iter(())
        return all(any(is_excerpt(x, y) for y in rest) for x in part)
    return part == whole


def test_is_excerpt_refuses_changed_values():
    whole = {"a": {"b": 1, "c": 2}, "s": [{"t": "x", "r": 1}, {"t": "y", "r": 2}]}
    assert is_excerpt({"a": {"b": 1}, "s": [{"t": "y"}]}, whole)
    assert not is_excerpt({"a": {"b": 3}}, whole)
    assert not is_excerpt({"s": [{"t": "y"}, {"t": "x"}]}, whole)  # order matters
    assert not is_excerpt({"s": [{"t": "z"}]}, whole)


EXCERPTS = [b for page in DOCS for b in blocks_of(page) if b.lang == "toml" and b.code.startswith("# from scenes/")]


@pytest.mark.parametrize("block", EXCERPTS, ids=[f"{b.page}:{b.line}" for b in EXCERPTS])
def test_toml_excerpts_match_their_scene_file(block):
    """A scene-file excerpt shown in the docs says what the file holds: same tables, same values."""
    name = block.code.splitlines()[0].removeprefix("# from ").strip()
    whole = tomllib.loads((ROOT / name).read_text(encoding="utf-8"))
    assert is_excerpt(tomllib.loads(block.code), whole), f"{block.page}:{block.line} is not an excerpt of {name}"


def test_pipelines_keyframes_are_an_excerpt_of_anim_toml():
    assert any(b.page == "docs/pipelines.md" for b in EXCERPTS)


def test_tests_named_in_the_docs_exist():
    """``tests/test_x.py::test_name`` in the docs names a test function that exists (a renamed
    test leaves the docs pointing nowhere)."""
    named = set()
    for page in DOCS:
        named |= set(re.findall(r"(tests/[\w/]+\.py)::(\w+)", page.read_text(encoding="utf-8")))
    assert named
    missing = [f"{f}::{n}" for f, n in sorted(named)
               if not (ROOT / f).is_file() or not re.search(rf"^\s*def {n}\(", (ROOT / f).read_text(encoding="utf-8"), re.M)]
    assert not missing, missing
