"""The CUDA benchmark (benchmarks/gpu.py): its image comparison, its refusal without a CUDA device,
and the comparison it makes, run CPU against CPU where no GPU is present."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import gpu  # noqa: E402


def test_the_comparison_counts_what_differs():
    a = np.ones((4, 4, 3), np.float32)
    b = a.copy()
    b[0, 0, 0] = 1.5
    c = gpu.compare(a, b)
    assert not c["bit_identical"] and c["max_abs_diff"] == 0.5
    assert c["frac_values_differ"] == 1 / 48 and c["frac_values_differ_1e-4"] == 1 / 48
    assert c["relmse_vs_cpu"] == pytest.approx(0.25 / 48, rel=1e-12)
    same = gpu.compare(a, a.copy())
    assert same["bit_identical"] and same["relmse_vs_cpu"] == 0.0 and same["finite"]
    b[1, 1, 1] = np.nan
    assert not gpu.compare(a, b)["finite"]


def test_without_cuda_it_says_so_and_bad_arguments_are_refused(capsys):
    if not wp.is_cuda_available():
        assert gpu.main(["--scenes", "b"]) == 2
        assert "no CUDA device 'cuda:0' here" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        gpu.main(["--scenes", "bz"])
    with pytest.raises(SystemExit):
        gpu.main(["--modes", "plain,fast"])


def test_a_study_compares_one_by_one_with_packets_on_the_cpu():
    """study() on the CPU device (rays one by one there, as on CUDA) against the CPU's packets:
    the same image bit for bit, plain and adaptive."""
    row = gpu.study("b", "cpu", ["plain", "adaptive"], 2, 3, False, 1, packets=False)
    assert row["packets"] is False and row["scene"] == "two point lights"
    for mode in ("plain", "adaptive"):
        assert row["modes"][mode]["bit_identical"], mode
        assert row["modes"][mode]["mean_cpu"] > 0.05
