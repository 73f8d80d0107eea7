"""Shared fixtures. Warp's kernel cache goes under the repository (``.cache/warp``) unless
WARP_CACHE_PATH says otherwise, so a fresh clone compiles into a folder it owns.

Hypothesis profiles (the property tests in tests/stability/test_properties.py), chosen by the
environment variable WARPRT_HYPOTHESIS:

* ``quick`` (the default, what ``make test`` and CI run): derandomized, so every run on every
  machine tries the same examples (a failure reproduces everywhere); 100 examples as the unit
  that each test scales by its own weight; nothing written to ``.hypothesis/``.
* ``deep`` (``WARPRT_HYPOTHESIS=deep make test``): 20 times as many examples, fresh random seeds
  on every run, and ``print_blob=True``, so a failure prints the ``@reproduce_failure`` line that
  replays it.
"""

from __future__ import annotations

import os
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".cache" / "warp"))
# every test compiles the kernel it renders with in the foreground, so that which kernel ran a
# test never depends on a background compile's timing (tests/test_kernels.py tests that path)
os.environ.setdefault("WARPRT_BACKGROUND_COMPILE", "0")

import pytest  # noqa: E402
import warp as wp  # noqa: E402
from hypothesis import settings as _hyp_settings  # noqa: E402

import warprt._warp  # noqa: E402

warprt._warp.init()  # Warp initialised quietly, before _devices() asks it about CUDA

SCENES = ROOT / "scenes"

HYPOTHESIS_PROFILES = {
    "quick": dict(max_examples=100, derandomize=True, database=None, print_blob=False),
    "deep": dict(max_examples=2000, derandomize=False, database=None, print_blob=True),
}
for _name, _kw in HYPOTHESIS_PROFILES.items():
    _hyp_settings.register_profile(_name, **_kw)
_profile = os.environ.get("WARPRT_HYPOTHESIS", "quick") or "quick"
if _profile not in HYPOTHESIS_PROFILES:
    raise pytest.UsageError(f"WARPRT_HYPOTHESIS={_profile!r}: expected one of {', '.join(HYPOTHESIS_PROFILES)}")
_hyp_settings.load_profile(_profile)


def _devices() -> list[str]:
    devices = ["cpu"]
    if wp.is_cuda_available():
        devices.append("cuda:0")
    return devices


@pytest.fixture(params=_devices())
def device(request) -> str:
    """Every Warp device here: the CPU always, CUDA when present."""
    return request.param


@pytest.fixture
def cuda_device() -> str:
    if not wp.is_cuda_available():
        pytest.skip("needs a CUDA device")
    return "cuda:0"


def _variants_built() -> dict:
    """The render-kernel variants (single-image and batch) and other warprt modules this process
    built."""
    from warprt import aov, integrator, query, worlds

    keys = sorted(f.key + ("" if packets else " one by one") for (f, packets) in integrator.kernels_for.built())
    batch = sorted(f.key + ("" if packets else " one by one") for (f, packets) in worlds.batch_kernel_for.built())
    extra = [name for name, factory in (("query", query._query_kernels), ("aov", aov._aov_kernel)) if factory.built()]
    return {"variants": keys, "batch_variants": batch, "other_modules": extra}


_WORKER_RECORDS: list[dict] = []  # under pytest-xdist: what each worker process built


def pytest_sessionfinish(session):
    """An xdist worker hands what it built to the controller (``pytest_testnodedown``)."""
    if hasattr(session.config, "workeroutput"):
        session.config.workeroutput["warprt_built"] = _variants_built()


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    record = getattr(node, "workeroutput", {}).get("warprt_built")
    if record:
        _WORKER_RECORDS.append(record)


def pytest_terminal_summary(terminalreporter):
    """Report (and record for the benchmarks) how many render-kernel variants this run built
    (with ``-n``: in all its worker processes together): each is one Warp module, a few seconds
    of compile on a cold cache."""
    import json

    records = [_variants_built()] + _WORKER_RECORDS
    keys = sorted({k for r in records for k in r["variants"]})
    batch = sorted({k for r in records for k in r.get("batch_variants", ())})
    extra = [name for name in ("query", "aov") if any(name in r["other_modules"] for r in records)]
    record = {"render_kernel_variants": len(keys), "variants": keys, "batch_kernel_variants": len(batch),
              "batch_variants": batch, "other_modules": extra}
    terminalreporter.write_line(f"warprt kernel variants built: {len(keys)} render ({', '.join(keys)})"
                                + f"; {len(batch)} batch ({', '.join(batch)})"
                                + "".join(f" + the {name} module" for name in extra))
    try:
        path = ROOT / ".cache" / "test-kernel-variants.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1))
    except OSError:
        pass
