"""Mutation testing: does the suite notice a one-line mistake in the physics?

``make mutate`` (or ``python -m tests.mutate``) applies each mutation listed in
``tests/mutations.toml`` (a line of a source file replaced by a wrong one: a missing clamp, a
swapped weight, a wrong constant) to a temporary copy of the repository, runs only the tests
that cover it there, and prints CAUGHT when they fail and MISSED when they pass. The working tree
is never modified, so an interrupted run leaves nothing behind. First every distinct test
selection runs once unmutated and must pass (a selection that fails anyway would "catch"
everything). Exit status: 0 when every mutation is caught, 1 when any is missed, 2 when the list
is stale (a ``find`` line no longer occurs exactly once in its file), a selection fails
unmutated, or a test run could not start.

Mutated kernels compile into their own cache (``.cache/warp-mutate``), keyed by their source, so
a second run of the list is faster and the main kernel cache stays clean.

Options: ``--only NAME`` (substring of the mutation names, repeatable), ``--list``, ``--timeout S``
per mutation (a run that times out counts as caught: a hung suite fails in CI), ``-v`` to show the
test output of missed mutations.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIST = ROOT / "tests" / "mutations.toml"
COPY = ("warprt", "tests", "scenes", "examples", "benchmarks", "docs", "pyproject.toml", "README.md")


@dataclass(frozen=True)
class Mutation:
    name: str
    file: str
    find: str
    replace: str
    tests: tuple[str, ...]
    why: str = ""


def load(path: Path = LIST) -> list[Mutation]:
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    out = []
    for i, m in enumerate(data.get("mutation", [])):
        missing = [k for k in ("name", "file", "find", "replace", "tests") if k not in m]
        if missing:
            raise SystemExit(f"{path.name}: mutation[{i}] lacks {', '.join(missing)}")
        if "\n" in m["find"] or "\n" in m["replace"]:
            raise SystemExit(f"{path.name}: mutation {m['name']!r}: find and replace are single lines")
        if m["find"] == m["replace"]:
            raise SystemExit(f"{path.name}: mutation {m['name']!r} changes nothing")
        out.append(Mutation(m["name"], m["file"], m["find"], m["replace"], tuple(m["tests"]), m.get("why", "")))
    names = [m.name for m in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise SystemExit(f"{path.name}: duplicate names {sorted(dup)}")
    return out


def check_applies(m: Mutation, root: Path = ROOT) -> str:
    """The mutated text of m's file; SystemExit(2) if ``find`` is not exactly one whole line."""
    text = (root / m.file).read_text(encoding="utf-8")
    lines = text.split("\n")
    hits = [i for i, line in enumerate(lines) if line == m.find]
    if len(hits) != 1:
        raise StaleList(f"{m.name}: the line {m.find!r} occurs {len(hits)} times in {m.file} (must be once)")
    lines[hits[0]] = m.replace
    return "\n".join(lines)


class StaleList(Exception):
    pass


def copy_tree(dst: Path) -> None:
    for name in COPY:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dst / name, ignore=shutil.ignore_patterns("__pycache__", ".cache", "*.pyc"))
        elif src.exists():
            shutil.copy2(src, dst / name)


def pytest(work: Path, tests: tuple[str, ...], timeout: float) -> tuple[int, str]:
    """Run pytest on ``tests`` in the copy ``work``: (exit status, output); -1 on timeout."""
    env = dict(os.environ, PYTHONPATH=str(work), WARP_CACHE_PATH=str(ROOT / ".cache" / "warp-mutate"),
               PYTHONDONTWRITEBYTECODE="1")
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
                              cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
        return proc.returncode, proc.stdout + proc.stderr
    except subprocess.TimeoutExpired:
        return -1, "timed out"


def baseline(muts: list[Mutation], work: Path, timeout: float) -> None:
    """Each distinct test selection must pass on the unmutated copy (else a failure would count
    as a catch): StaleList otherwise."""
    for tests in dict.fromkeys(m.tests for m in muts):
        code, output = pytest(work, tests, timeout)
        if code != 0:
            raise StaleList(f"the tests {' '.join(tests)} fail without any mutation (exit {code}):\n{output[-2000:]}")


def run_one(m: Mutation, work: Path, timeout: float, verbose: bool) -> tuple[str, float]:
    original = (work / m.file).read_text(encoding="utf-8")
    (work / m.file).write_text(check_applies(m, work), encoding="utf-8")
    t0 = time.perf_counter()
    try:
        code, output = pytest(work, m.tests, timeout)
    finally:
        (work / m.file).write_text(original, encoding="utf-8")
    dt = time.perf_counter() - t0
    if code == 1 or code == -1:
        return "CAUGHT", dt
    if code == 0:
        if verbose:
            print(output[-3000:])
        return "MISSED", dt
    raise StaleList(f"{m.name}: pytest could not run its tests (exit {code}):\n{output[-2000:]}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", default=[], help="run mutations whose name contains this")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per mutation")
    ap.add_argument("--no-baseline", action="store_true",
                    help="skip the check that each test selection passes unmutated")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    muts = load()
    if args.only:
        muts = [m for m in muts if any(s in m.name for s in args.only)]
    try:
        for m in muts:
            check_applies(m)
    except StaleList as e:
        print(f"stale mutation list: {e}", file=sys.stderr)
        return 2
    if args.list:
        for m in muts:
            print(f"{m.name:55s} {m.file}  ->  {' '.join(m.tests)}")
        return 0
    results = []
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="warprt-mutate-") as tmp:
        work = Path(tmp)
        copy_tree(work)
        if not args.no_baseline:
            t0 = time.perf_counter()
            try:
                baseline(muts, work, args.timeout)
            except StaleList as e:
                print(f"error: {e}", file=sys.stderr)
                return 2
            print(f"baseline: every test selection passes unmutated ({time.perf_counter() - t0:.0f} s)", flush=True)
        for k, m in enumerate(muts, 1):
            try:
                verdict, dt = run_one(m, work, args.timeout, args.verbose)
            except StaleList as e:
                print(f"error: {e}", file=sys.stderr)
                return 2
            results.append((m, verdict))
            print(f"[{k:2d}/{len(muts)}] {verdict:6s} {dt:6.1f} s  {m.name}", flush=True)
    caught = sum(v == "CAUGHT" for _, v in results)
    missed = [m for m, v in results if v == "MISSED"]
    print(f"\n{caught} of {len(results)} mutations caught in {time.perf_counter() - t_all:.0f} s"
          + (f"; missed: {', '.join(m.name for m in missed)}" if missed else ""))
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
