"""Figures quoted in the docs come from docs/benchmarks/results.json (written by
``python -m benchmarks.run``) and newton.json: each entry below names a doc, a pattern that must
occur in it exactly once (so a reworded or deleted quote fails here rather than going unchecked),
and the JSON value each captured number must equal, to the precision it is quoted with (half a
unit of its last digit). A range "a–b" is checked against the min and max of its JSON values.
docs/benchmarks.md's figures are in its generated tables (``benchmarks.docs``;
tests/test_benchmark_docs.py checks that they are what the files give): the entries for it here
read them back independently of that code, so a table that quotes the wrong field fails too.

The kernel specialisation ratio is quoted in three docs; once results.json records its spread
over repeats (``full_over_specialised_min`` / ``_max``), each of them must also quote that spread
as "(a–b× over N interleaved pairs)", e.g. right after the ratio.
"""

from __future__ import annotations

import json
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = json.loads((ROOT / "docs" / "benchmarks" / "results.json").read_text())
# the side-by-side with Newton's camera (python -m benchmarks.newton_bench), under "newton/..."
RESULTS["newton"] = json.loads((ROOT / "docs" / "benchmarks" / "newton.json").read_text())
N = r"(\d+(?:\.\d+)?)"  # a quoted number
SPEC = "specialisation/full_over_specialised"
SPREAD = r"(?:\s\([^)]*\))?"  # the spread that may follow a ratio (checked by its own test below)

# (doc, pattern with one group per number, one JSON path per group; a tuple of paths: a range)
FIGURES = [
    ("README.md", rf"on a plain scene the full kernel\stakes {N}×{SPREAD}\sthe time of `basic`", [SPEC]),
    ("docs/architecture.md", rf"the full kernel takes\s{N}×{SPREAD}\sthe time of `basic` on a plain scene", [SPEC]),
    ("README.md", rf"and {N} s for\s`Features.full\(\)` in a fresh process", ["compile/full/compile_s"]),
    # docs/benchmarks.md, its generated tables: the specialised kernel against the full one
    ("docs/benchmarks.md", rf"\| `basic` \(the scene's own\) \| {N} \|", ["specialisation/specialised_s"]),
    ("docs/benchmarks.md", rf"\| `Features.full\(\)` \| {N} \|", ["specialisation/full_s"]),
    ("docs/benchmarks.md", rf"takes \*\*{N}×\*\*{SPREAD} the time of `basic`", [SPEC]),
    # throughput and thread scaling
    ("docs/benchmarks.md", rf"\| 1 \| {N} \| {N} \| {N} \|",
     ["throughput/1/seconds", "throughput/1/mrays_per_s", "throughput/1/mpixel_samples_per_s"]),
    ("docs/benchmarks.md", rf"\| 2 \| {N} \| {N} \| {N} \|",
     ["throughput/2/seconds", "throughput/2/mrays_per_s", "throughput/2/mpixel_samples_per_s"]),
    ("docs/benchmarks.md", rf"\*\*{N}×\*\* from 1 to 2 workers", ["throughput/speedup"]),
    ("docs/benchmarks.md", rf"The plain scene on one worker: \*\*{N} Mrays/s\*\*",
     ["throughput/plain_primary_shadow_mrays_per_s_per_core"]),
    # compile cost: cold compile and the whole fresh process, per variant
    ("docs/benchmarks.md", rf"\| `basic` \| +\| {N} s \| {N} s \|", ["compile/basic/compile_s", "compile/basic/process_s"]),
    *[("docs/benchmarks.md", rf"\| `{v}` alone \| +\| {N} s \| {N} s \|",
       [f"compile/{v}/compile_s", f"compile/{v}/process_s"]) for v in ("meshes", "area_lights", "secondary", "refraction", "glossy", "lens", "motion")],
    ("docs/benchmarks.md", rf"\| `Features.full\(\)` \| `[a-z_+]+` \| {N} s \| {N} s \|",
     ["compile/full/compile_s", "compile/full/process_s"]),
    ("docs/benchmarks.md", rf"\| `Features.full\(\)`, already cached \| `[a-z_+]+` \| {N} s \| {N} s \|",
     ["compile/cached/compile_s", "compile/cached/process_s"]),
    # warprt against Newton's SensorCamera
    *[("docs/benchmarks.md",
       rf"\| \({key}\) [^|]* \| {N} \| {N} \| {N} \| \*\*{N}×\*\* \({N}–{N}×\) \| {N}× \| {N}× \|",
       [f"newton/cases/{key}/newton/mpix_s", f"newton/cases/{key}/warprt/mpix_s",
        f"newton/cases/{key}/warprt_1core/mpix_s", f"newton/cases/{key}/speed_ratio",
        f"newton/cases/{key}/speed_ratio_spread/0", f"newton/cases/{key}/speed_ratio_spread/1",
        f"newton/cases/{key}/speed_ratio_1core", f"newton/cases/{key}/speed_ratio_cpu"]) for key in ("a", "b")],
    ("docs/benchmarks.md", rf"from `state.body_q` takes {N} ms", ["newton/cases/a/pose_update/update_ms_median"]),
    # the device check of a batch's inputs
    *[("docs/benchmarks.md", rf"\| {label} \| {N} \| {N} ms \| {N} ms \| {N}% \|",
       [f"checks/{key}/elements", f"checks/{key}/check_ms", f"checks/{key}/render_ms_unchecked",
        f"checks/{key}/check_percent"])
      for label, key in (("1 world × 1 camera, 16×16", "one_tiny"), ("256 worlds × 2 cameras, 16×16", "many_small"),
                         ("8 worlds × 2 cameras, 128×128", "few_large"))],
    # equal-error speed-ups over independent sampling (the two-column table only)
    *[("docs/benchmarks.md", rf"\| {label} \| {N}× \| {N}× \|\n", [f"error/{key}/stratified", f"error/{key}/sobol"])
      for label, key in (("soft shadows", "soft_shadows"), ("depth of field", "depth_of_field"),
                         (r"antialiasing \(edges\)", "antialiasing"), ("glossy reflection", "glossy"),
                         ("motion blur", "motion_blur"))],
]


def json_value(path: str) -> float:
    """The number at a "/"-separated path; a key may itself hold "/" ("error" is keyed
    "soft_shadows/stratified"), so the longest key present is taken at each level."""
    node, parts = RESULTS, path.split("/")
    while parts:
        if isinstance(node, list):  # a list: the next part is an index
            node, parts = node[int(parts[0])], parts[1:]
            continue
        k = next((k for k in range(len(parts), 0, -1) if "/".join(parts[:k]) in node), None)
        if k is None:
            raise KeyError(f"{path}: no {parts[0]!r} in results.json")
        node, parts = node["/".join(parts[:k])], parts[k:]
    return float(node)


def decimals(text: str) -> int:
    return len(text.split(".")[1]) if "." in text else 0


def check(quoted: str, expected: float, what: str):
    half_unit = 0.5 * 10.0 ** -decimals(quoted)
    assert abs(float(quoted) - expected) <= half_unit * (1 + 1e-9), (what, quoted, expected)


@pytest.mark.parametrize("doc, pattern, paths", FIGURES, ids=[f"{d}: {p[:40]}" for d, p, _ in FIGURES])
def test_quoted_figure_matches_results_json(doc, pattern, paths):
    text = (ROOT / doc).read_text()
    found = re.findall(pattern, text)
    assert len(found) == 1, f"{doc}: {pattern!r} occurs {len(found)} times (expected once)"
    groups = list(found[0]) if isinstance(found[0], tuple) else [found[0]]
    for path in paths:
        if isinstance(path, tuple):
            values = [json_value(p) for p in path]
            check(groups.pop(0), min(values), f"{doc}: min of {path}")
            check(groups.pop(0), max(values), f"{doc}: max of {path}")
        else:
            check(groups.pop(0), json_value(path), f"{doc}: {path}")
    assert not groups


def test_the_specialisation_ratio_is_quoted_with_its_spread_when_the_json_has_one():
    spec = RESULTS["specialisation"]
    quotes = {doc: (ROOT / doc).read_text() for doc in ("README.md", "docs/architecture.md", "docs/benchmarks.md")}
    if "full_over_specialised_min" in spec:
        spread = re.escape(f"({spec['full_over_specialised_min']:.2f}–{spec['full_over_specialised_max']:.2f}× "
                           f"over {spec['rounds']} interleaved pairs)")
        for doc, text in quotes.items():
            assert re.search(spread, text), f"{doc} quotes the specialisation ratio without its spread {spread!r}"
    else:  # an older results.json: the docs say that it holds no spread
        assert "kept only that median, not its spread" in quotes["docs/benchmarks.md"]
    # the figure that used to be quoted and did not survive re-measurement
    for doc, text in quotes.items():
        assert "6–9%" not in text, doc
