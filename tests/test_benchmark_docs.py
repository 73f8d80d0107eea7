"""docs/benchmarks.md's tables are generated (``benchmarks.docs``) from the results committed under
docs/benchmarks/: each one must be what its file gives, the markers must be where the code looks
for them, a missing file must say which command writes it, and the page must describe the method,
not the history of runs. The figures the tables quote are read back against the JSON by
tests/test_doc_figures.py, independently of the code that wrote them."""

from __future__ import annotations

import json
import math
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import docs  # noqa: E402

PAGE = ROOT / "docs" / "benchmarks.md"


def test_every_table_is_what_its_committed_file_gives():
    assert docs.stale() == [], "run: python -m benchmarks.docs"


def test_every_block_is_on_the_page_once_and_every_driver_names_a_known_one():
    text = PAGE.read_text()
    for name in docs.BLOCKS:
        assert text.count(docs.end_marker(name)) == 1, name
        assert len(re.findall(rf"<!-- {name}:begin\b", text)) == 1, name
    assert set(docs.RUN_BLOCKS) <= set(docs.BLOCKS)
    for driver in ("run", "peers", "corpus", "newton_bench", "ablation", "gpu"):
        source = (ROOT / "benchmarks" / f"{driver}.py").read_text()
        called = re.findall(r"docs\.update\((\[[^\]]*\]|docs\.RUN_BLOCKS)\)", source)
        assert called, f"benchmarks/{driver}.py does not re-render its tables"
        for names in called:
            if names != "docs.RUN_BLOCKS":
                assert set(eval(names)) <= set(docs.BLOCKS), (driver, names)


def _page(tmp_path, body: str) -> Path:
    p = tmp_path / "page.md"
    p.write_text(body)
    return p


def test_replace_block_touches_only_its_block(tmp_path):
    p = _page(tmp_path, "# t\n\nbefore\n<!-- a:begin (old words) -->\nold\n<!-- a:end -->\nafter\n"
                        "<!-- b:begin -->\nkeep\n<!-- b:end -->\n")
    assert docs.replace_block(p, "a", "| x |\n")
    assert p.read_text() == ("# t\n\nbefore\n" + docs.begin_marker("a") + "\n\n| x |\n\n" + docs.end_marker("a")
                             + "\nafter\n<!-- b:begin -->\nkeep\n<!-- b:end -->\n")
    assert docs.block_text(p, "a") == "| x |" and docs.block_text(p, "b") == "keep"
    assert not docs.replace_block(p, "a", "| x |"), "an unchanged block must not rewrite the file"
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize("body", ["no markers\n", "<!-- a:begin -->\n<!-- a:end -->\n<!-- a:begin -->\n<!-- a:end -->\n",
                                  "<!-- a:end -->\n<!-- a:begin -->\n", "<!-- a:begin -->\nonly the start\n"])
def test_a_missing_or_repeated_marker_is_an_error_naming_the_file_and_block(tmp_path, body):
    p = _page(tmp_path, body)
    with pytest.raises(ValueError, match=r"page\.md: block 'a'"):
        docs.replace_block(p, "a", "x")
    assert p.read_text() == body


def test_without_results_every_block_names_the_command_that_writes_them(tmp_path):
    for name, block in docs.BLOCKS.items():
        text = docs.render(name, tmp_path)
        assert text.startswith("*Not measured yet") and "`python -m benchmarks." in text, name
    with pytest.raises(KeyError):
        docs.render("levers")


def test_check_and_update_from_the_command_line(tmp_path, capsys):
    page = tmp_path / "benchmarks.md"
    shutil.copyfile(PAGE, page)
    assert docs.main(["--check", "--doc", str(page)]) == 0
    docs.replace_block(page, "growth", "| stale |")
    assert docs.main(["--check", "--doc", str(page)]) == 1
    assert "growth" in capsys.readouterr().out
    assert docs.main(["growth", "--doc", str(page)]) == 0
    assert page.read_text() == PAGE.read_text()
    with pytest.raises(SystemExit):
        docs.main(["levers"])
    assert docs.main(["--check", "--doc", str(_page(tmp_path, "no markers\n"))]) == 2


def test_the_error_slopes_are_least_squares_fits_from_4_spp():
    # MSE = c / spp^1.5 exactly: the slope is -1.5 whatever c, and points below 4 spp are ignored
    pts = [(s, 0.0, 3.0 / s ** 1.5) for s in (4, 8, 16, 32)] + [(1, 0.0, 1.0), (2, 0.0, 1.0)]
    assert docs._slope(pts) == pytest.approx(-1.5, abs=1e-12)
    assert docs._slope([(1, 0.0, 1.0), (4, 0.0, 0.5)]) is None


def _ablation_json():
    def mech(ratio, identical=True):
        return {"ratio": ratio, "spread": [ratio - 0.01, ratio + 0.02], "cpu_ratio": ratio, "seconds": [],
                "cpu_seconds": [], "identical": identical}

    def scene(key, mechanisms):
        return {"key": key, "label": key, "kind": "k", "spp": 16,
                "workers": {"1": {"on_min": 0.2, "mechanisms": mechanisms, "differ": []},
                            "2": {"on_min": 0.1, "mechanisms": mechanisms, "differ": []}}}

    return {"config": "sobol+split+adaptive", "repeats": 5, "workers": [1, 2],
            "host": {"cpus": 2, "python": "3.11", "warp": "1.19"},
            "mechanisms": {"light_buffers": {}, "camera_bins": {}, "unused": {}},
            "scenes": [scene("a", {"light_buffers": mech(1.21), "camera_bins": mech(1.5, identical=False)}),
                       scene("d", {"light_buffers": mech(1.44)})]}


def test_the_ablation_table(tmp_path):
    (tmp_path / "ablation.json").write_text(json.dumps(_ablation_json()))
    text = docs.render("ablation", tmp_path)
    row = next(line for line in text.splitlines() if line.startswith("| `light_buffers`"))
    # geometric means over every scene and over those using it, computed here
    assert row == (f"| `light_buffers` | 1.21 (1.20–1.23) | 1.44 (1.43–1.46) | {math.sqrt(1.21 * 1.44):.3f} | "
                   f"{math.sqrt(1.21 * 1.44):.3f} (2) |")
    bins = next(line for line in text.splitlines() if line.startswith("| `camera_bins`"))
    assert "**image differs**" in bins and "| — |" in bins and f"| {math.sqrt(1.5):.3f} | 1.500 (1) |" in bins
    assert "`unused`" not in text, "a mechanism no scene uses gets no row"
    assert text.count("all on, ms | 200 | 200") == 1 and text.count("all on, ms | 100 | 100") == 1
    assert "spp per scene: a 16, d 16" in text


def test_the_gpu_table(tmp_path):
    same = {"bit_identical": True, "relmse_vs_cpu": 0.0, "max_abs_diff": 0.0, "frac_values_differ": 0.0}
    off = {"bit_identical": False, "relmse_vs_cpu": 5.2e-16, "max_abs_diff": 2.5e-7, "frac_values_differ": 0.025}
    (tmp_path / "gpu.json").write_text(json.dumps({
        "device": "NVIDIA X", "warp": "1.19.0", "spp": 4, "seed": 3, "scenes": {
            "b": {"scene": "two point lights", "packets": False, "compile_s": 4.5, "modes": {"plain": same},
                  "t64_s": 0.0012, "t1024_s": 0.018, "msamples_s_1024": 3728.4},
            "f": {"scene": "penumbrae, thin lens", "packets": False, "compile_s": 54.0,
                  "modes": {"plain": off, "adaptive": same}}}}))
    text = docs.render("gpu", tmp_path)
    assert "| (b) two point lights | one by one | plain: bit-identical | 1.2 ms | 18.0 ms | 3728 | 4.5 s |" in text
    assert ("| (f) penumbrae, thin lens | one by one | plain: relMSE 5.2e-16, 2.5% of the values differ, by at most "
            "2.5e-07; adaptive: bit-identical | – | – | – | 54.0 s |") in text
    assert "NVIDIA X, Warp 1.19.0" in text


def test_the_corpus_tables(tmp_path):
    def ratio(r):
        return {"ratio": r, "bound": "", "per_repeat": [r, r * 1.1]}

    machine = {"mitsuba": "3.9.1", "variant": "llvm_ad_rgb", "warprt": "0.1.0", "warp": "1.19.0", "cpus": 2,
               "cpu": "AMD EPYC", "simd": "AVX-512", "python": "3.11.7"}
    conv = {"agree": True, "ratio_to_noise": 1.02, "mean_rel_diff": 1e-5, "mean_within_noise": True, "mean_z": 0.3}
    results = {"machine": machine, "quick": False, "whole": True, "configs": ["defaults"], "wall_s": 3000.0,
               "settings": {"repeats": 3},
               "scenes": {"fence": {"name": "fence", "kind": "edges", "split": "train", "width": 256, "height": 256,
                                    "peer": True, "convergence": conv,
                                    "time_to_error": {"0.001": {"mitsuba/multijitter": {"seconds": 0.5, "how": "interp"}},
                                                      "0.01": {}},
                                    "ratios": {"0.001": {"defaults": ratio(0.8)}, "0.01": {}}}}}
    (tmp_path / "corpus.json").write_text(json.dumps(results))
    text = docs.render("corpus", tmp_path)
    assert "| fence | edges | 256×256 | yes: 1.02×, +0.001% | 0.500 s | 0.80 (0.80–0.88) |" in text
    assert "**0.80** (0.80–0.88)" in text and "The whole run took 50 minutes" in text
    (tmp_path / "corpus.json").write_text(json.dumps({**results, "quick": True}))
    assert docs.render("corpus", tmp_path).startswith("*Not measured yet"), "a quick run is not the corpus's result"


def _outside_blocks(text: str) -> str:
    return re.sub(r"<!-- (\w+):begin\b.*?<!-- \1:end -->", "", text, flags=re.S)


def test_the_page_describes_the_software_not_the_history_of_its_runs():
    prose = _outside_blocks(PAGE.read_text())
    for pattern in (r"\b20\d\d-\d\d-\d\d\b", r"(?i)\bsessions?\b", r"(?i)fresh clone", r"(?i)\blevers?\b",
                    r"(?i)\b(?:this|last|earlier|previous) run\b", r"(?i)\bbefore (?:the|its|this)\b.*\bwas\b"):
        found = re.findall(pattern, prose)
        assert not found, (pattern, found[:3])
    assert len(PAGE.read_bytes()) < 60_000, "a page a new user reads in minutes"
